#!/usr/bin/env bash
# End-to-end test of the `pbgi` command: every subcommand on a small scene, the properties of
# what they write, and clear errors (non-zero exit, a message naming the problem) on bad input.
# Usage: cli_test.sh PBGI_BINARY SCRATCH_DIR
set -uo pipefail
pbgi="$1"
dir="$2"
rm -rf "$dir"
mkdir -p "$dir"
failures=0
passes=0

ok() { passes=$((passes + 1)); }
fail() { echo "FAIL: $*" >&2; failures=$((failures + 1)); }

# run NAME CMD...: must exit 0.
run() {
  local name="$1"; shift
  if "$@" >"$dir/$name.out" 2>"$dir/$name.err"; then ok; else
    fail "$name exited $? : $(tail -n 3 "$dir/$name.err")"; fi
}
# refuse NAME PATTERN CMD...: must exit non-zero with PATTERN in stderr.
refuse() {
  local name="$1" pattern="$2"; shift 2
  if "$@" >"$dir/$name.out" 2>"$dir/$name.err"; then
    fail "$name succeeded but should have failed"
  elif ! grep -qiE "$pattern" "$dir/$name.err"; then
    fail "$name: stderr does not match '$pattern': $(head -c 300 "$dir/$name.err")"
  else ok; fi
}

run generate "$pbgi" generate cornell -n 30000 -o "$dir/c.ply" --seed 3 --keep-hidden
run build "$pbgi" build "$dir/c.ply" -o "$dir/c.pbgi" --memory 64M --stats-json "$dir/stats.json"
run info "$pbgi" info "$dir/c.pbgi" --json
grep -qE '"point_count"[^0-9]*30000\b' "$dir/info.out" && ok || fail "info --json does not report 30000 points: $(head -c 400 "$dir/info.out")"
run verify "$pbgi" verify "$dir/c.pbgi"
run query "$pbgi" query "$dir/c.pbgi" --at 0.5,0.5,0.02 --normal 0,0,1 --json
grep -q 'clusters' "$dir/query.out" && ok || fail "query --json prints no clusters"
run shade_points "$pbgi" shade "$dir/c.pbgi" --receivers "$dir/c.ply" -o "$dir/shaded.ply" \
  --mode irradiance --raster-res 8
# The output has one vertex per receiver.
count=$(grep -a -m1 '^element vertex' "$dir/shaded.ply" | awk '{print $3 + 0}')
[ "$count" = "30000" ] && ok || fail "shaded.ply has '$count' vertices, not 30000"
run shade_view "$pbgi" shade "$dir/c.pbgi" --scene cornell --seed 3 -o "$dir/view.exr" \
  --width 48 --height 32 --raster-res 8
[ -s "$dir/view.exr" ] && [ -s "$dir/view.png" ] && ok || fail "shade --scene wrote no images"
run demo "$pbgi" demo -o "$dir/demo" --scene cornell --points 40000 --width 48 --height 32 \
  --memory 64M --cache 16M
for f in occlusion indirect direct composite; do
  [ -s "$dir/demo/cornell_$f.png" ] && [ -s "$dir/demo/cornell_$f.exr" ] && ok || fail "demo wrote no $f image"
done
run eval "$pbgi" eval cornell -o "$dir/eval" --points 30000 --receivers 40 --rays 256 \
  --ray-sweep 16 64 --solid-angles 0.1 0.03 --raster-res 8 12
[ -s "$dir/eval/eval.json" ] && [ -s "$dir/eval/eval.png" ] && ok || fail "eval wrote no json/chart"
grep -q '"speedup_at_equal_error"' "$dir/eval/eval.json" && ok || fail "eval.json lacks the speed ratio"
# Both cut criteria in one sweep; the cosine-weighted cut gathers fewer clusters at equal msa.
run eval_cuts "$pbgi" eval cornell -o "$dir/eval_cuts" --points 30000 --receivers 40 --rays 256 \
  --ray-sweep 16 --solid-angles 0.03 --raster-res 8 --cuts plain cosine
plain=$(awk '$1 == "pbgi" && $6 == "plain" {print $11}' "$dir/eval_cuts.out")
cosine=$(awk '$1 == "pbgi" && $6 == "cos" {print $11}' "$dir/eval_cuts.out")
awk -v p="$plain" -v c="$cosine" 'BEGIN {exit !(p > 0 && c > 0 && c < p)}' && ok ||
  fail "eval --cuts: cosine clusters '$cosine' not fewer than plain '$plain'"
# eval --view: the reference, PBGI and error images and the figures, for a small view.
run eval_view "$pbgi" eval --view cornell -o "$dir/eval_view" --points 30000 --width 48 \
  --height 32 --rays 256
for f in reference.png pbgi_msa0.03_res12_cos.png error_msa0.03_res12_cos.png view.json \
  pbgi_msa0.03_res12_cos_shared_s8_t0.05.png shaded_msa0.03_res12_cos_shared_s8_t0.05.png; do
  [ -s "$dir/eval_view/$f" ] && ok || fail "eval --view wrote no $f"
done
grep -q '"mode": "shared"' "$dir/eval_view/view.json" && ok || fail "view.json lacks the shared row"
# The reference mode: demo --exact shades every receiver on its own; the default shares.
run demo_exact "$pbgi" demo -o "$dir/demo_exact" --scene cornell --points 40000 --width 48 \
  --height 32 --memory 64M --cache 16M --exact
grep -q 'sharing        none' "$dir/demo_exact.out" && ok || fail "demo --exact shared work"
grep -q 'interpolated' "$dir/demo.out" && ok || fail "demo prints no sharing line"
grep -q '"worst_tile"' "$dir/eval_view/view.json" && grep -q '"p99"' "$dir/eval_view/view.json" &&
  ok || fail "view.json lacks the tile and tail figures"
# The figures are a real comparison: PBGI's MAE against the reference is small but not zero.
mae=$(awk '/^msa/ {for (i = 1; i < NF; ++i) if ($i == "MAE") {print $(i + 1); exit}}' "$dir/eval_view.out")
awk -v m="$mae" 'BEGIN {exit !(m > 0 && m < 0.1)}' && ok || fail "eval --view MAE '$mae' not in (0, 0.1)"
run shade_plain "$pbgi" shade "$dir/c.pbgi" --receivers "$dir/c.ply" -o "$dir/shaded_plain.ply" \
  --mode occlusion --raster-res 8 --cut plain
refuse bad_spacing "spacing" "$pbgi" shade "$dir/c.pbgi" --receivers "$dir/c.ply" -o "$dir/x.ply" --spacing 3
refuse bad_cut "cut" "$pbgi" shade "$dir/c.pbgi" --receivers "$dir/c.ply" -o "$dir/x.ply" --cut sideways

# Errors: what and where.
refuse missing_db "no such|not found|does not exist" "$pbgi" info "$dir/nope.pbgi"
refuse missing_ply "nope.ply" "$pbgi" build "$dir/nope.ply" -o "$dir/x.pbgi"
printf 'ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty float radius\nend_header\n0 0 0 0 0 1 0.1\n1 1 nan 0 0 1 0.1\n' > "$dir/nan.ply"
refuse nan_ply "record 1|vertex 1|nan" "$pbgi" build "$dir/nan.ply" -o "$dir/nan.pbgi"
refuse bad_scene "neither a procedural scene" "$pbgi" shade "$dir/c.pbgi" --scene nosuchscene -o "$dir/v.png"
refuse both_inputs "either --receivers" "$pbgi" shade "$dir/c.pbgi" -o "$dir/v.png"
refuse bad_size "not a size|SIZE" "$pbgi" build "$dir/c.ply" -o "$dir/y.pbgi" --memory lots
# A corrupt page: flip bytes in the middle of the data file; verify must name a page.
cp -r "$dir/c.pbgi" "$dir/corrupt.pbgi"
data="$dir/corrupt.pbgi/data.mdb"
if [ -f "$data" ]; then
  size=$(stat -c %s "$data")
  printf '\xff\xfe\xfd\xfc\xfb\xfa\xf9\xf8' | dd of="$data" bs=1 seek=$((size / 2)) conv=notrunc status=none
  refuse corrupt "page|corrupt|checksum" "$pbgi" verify "$dir/corrupt.pbgi"
else
  fail "no data.mdb in the database directory"
fi

echo "$passes passed, $failures failed"
[ "$failures" -eq 0 ]
