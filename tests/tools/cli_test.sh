#!/usr/bin/env bash
# End-to-end test of the `pbgi` command: every subcommand on a small scene, the properties of
# what they write, and clear errors (non-zero exit, a message naming the problem) on bad input.
# Usage: cli_test.sh PBGI_BINARY SCRATCH_DIR
source "$(dirname "$0")/harness.sh" "$@"
here="$(cd "$(dirname "$0")" && pwd)"

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
# --cache bounds the whole shade step: the process (about 17 MiB here), the view and the pages.
run demo "$pbgi" demo -o "$dir/demo" --scene cornell --points 40000 --width 48 --height 32 \
  --memory 64M --cache 64M
for f in occlusion indirect direct composite; do
  [ -s "$dir/demo/cornell_$f.png" ] && [ -s "$dir/demo/cornell_$f.exr" ] && ok || fail "demo wrote no $f image"
done
run eval "$pbgi" eval cornell -o "$dir/eval" --points 30000 --receivers 40 --rays 256 \
  --ray-sweep 16 64 --solid-angles 0.1 0.03 --raster-res 8 12
[ -s "$dir/eval/eval.json" ] && [ -s "$dir/eval/eval.png" ] && ok || fail "eval wrote no json/chart"
grep -q '"speedup_at_equal_error"' "$dir/eval/eval.json" && ok || fail "eval.json lacks the speed ratio"
# --convergence: the finer setting (4x the surfels, msa 0.005) on the same receivers and truth,
# each row's MAE over the default row's, as its own eval.json gives them.
run eval_conv "$pbgi" eval cornell -o "$dir/eval_conv" --points 20000 --receivers 40 --rays 256 \
  --ray-sweep 16 --solid-angles 0.03 --raster-res 12 --convergence --fine-raster-res 12 16 \
  --dump-receivers "$dir/conv.csv"
python3 - "$dir" <<'PY' && ok || fail "eval --convergence: convergence.json does not match the evals"
import json, sys
d = sys.argv[1]
c = json.load(open(d + "/eval_conv/convergence.json"))
base = json.load(open(d + "/eval_conv/eval.json"))
fine = json.load(open(d + "/eval_conv/finer/eval.json"))
pbgi = [r for r in fine["rows"] if r["method"] == "pbgi"]
assert c["default_mae"] == base["default_mae"] and c["default_setting"] == "msa 0.03 res 12 cos"
assert c["default_points"] == base["points"] and c["finer_points"] == fine["points"]
assert 3.9 * base["points"] < fine["points"] < 4.1 * base["points"]
assert len(c["rows"]) == len(pbgi) == 2 and c["receivers"] == fine["receivers"] == 40
for r, f in zip(c["rows"], pbgi):
    assert f["setting"].startswith("msa 0.005 res ") and r["setting"].startswith(f["setting"])
    assert abs(r["ratio"] - f["mae"] / base["default_mae"]) < 1e-12
best = min(r["ratio"] for r in c["rows"])
assert c["best_ratio"] == best and c["met"] == (best <= 0.5)
# Both settings against one truth: the same receivers and reference values, row by row.
rows = [open(d + f).read().splitlines() for f in ("/conv.csv", "/conv.finer.csv")]
assert len(rows[0]) == len(rows[1]) == 41
assert all(a.split(",")[:8] == b.split(",")[:8] for a, b in zip(*rows))
assert base["truth_mean"] == fine["truth_mean"] and base["truth_noise_mae"] == fine["truth_noise_mae"]
PY
refuse eval_conv_view "not with --view" "$pbgi" eval --view cornell --convergence -o "$dir/ecv"
refuse eval_conv_glossy "or .-mode glossy" "$pbgi" eval cornell --mode glossy --convergence -o "$dir/ecv"
refuse eval_conv_default "must include it" "$pbgi" eval cornell --convergence --raster-res 8 \
  -o "$dir/ecv"
refuse eval_conv_flag "is for --convergence" "$pbgi" eval cornell --fine-raster-res 16 -o "$dir/ecv"
# --dump-receivers on a receiver set: one row per receiver, its error its PBGI value less its
# reference, and its sheet tag last: 0 on the forest's one-sided ground and trunks, 1-255 on
# its two-sided leaves (pixel_error --sheet takes it).
run eval_dump "$pbgi" eval forest --size 2 -o "$dir/eval_dump" --points 20000 --receivers 60 \
  --rays 64 --ray-sweep 16 --solid-angles 0.03 --raster-res 12 --dump-receivers "$dir/rec.csv"
awk -F, 'NR == 1 {if ($11 != "sheet") bad++; next} {n++; d = $10 - ($9 - $8);
  if (d < -2e-6 || d > 2e-6 || $11 !~ /^[0-9]+$/ || $11 > 255) bad++;
  if ($7 > 0.999 && $4 < 0.01 && $11 != 0) bad++; if ($11 > 0) tagged++}
  END {exit !(n >= 50 && bad == 0 && tagged > 0)}' "$dir/rec.csv" && ok ||
  fail "eval --dump-receivers: rows, errors or sheet tags wrong"
# Both cut criteria in one sweep; the cosine-weighted cut gathers fewer clusters at equal msa.
run eval_cuts "$pbgi" eval cornell -o "$dir/eval_cuts" --points 30000 --receivers 40 --rays 256 \
  --ray-sweep 16 --solid-angles 0.03 --raster-res 8 --cuts plain cosine
plain=$(awk '$1 == "pbgi" && $6 == "plain" {print $12}' "$dir/eval_cuts.out")
cosine=$(awk '$1 == "pbgi" && $6 == "cos" {print $12}' "$dir/eval_cuts.out")
awk -v p="$plain" -v c="$cosine" 'BEGIN {exit !(p > 0 && c > 0 && c < p)}' && ok ||
  fail "eval --cuts: cosine clusters '$cosine' not fewer than plain '$plain'"
# eval --mode glossy: one eval per lobe setting against the reference of the same lobe.
run eval_glossy "$pbgi" eval cornell --mode glossy -o "$dir/eval_glossy" --points 30000 \
  --receivers 40 --rays 256 --ray-sweep 64 --solid-angles 0.03 --raster-res 12 \
  --lobes phong ggx --phong-exponents 8 32 --ggx-roughnesses 0.3
for f in eval-phong8 eval-phong32 eval-ggx0.3; do
  [ -s "$dir/eval_glossy/$f.json" ] && [ -s "$dir/eval_glossy/$f.png" ] && ok ||
    fail "eval --mode glossy wrote no $f.json/png"
done
grep -q '"ggx_roughness"' "$dir/eval_glossy/eval.json" && grep -q '"default_relative_mae"' \
  "$dir/eval_glossy/eval.json" && ok || fail "eval.json lacks the glossy lobes' figures"
rel=$(awk '$1 == "pbgi" && $6 == "lobe" {sub("%", "", $NF); print $NF; exit}' "$dir/eval_glossy.out")
awk -v r="$rel" 'BEGIN {exit !(r > 0 && r < 40)}' && ok ||
  fail "eval --mode glossy: relative MAE '$rel'% not in (0, 40)"
# eval --view --mode glossy: one lobe per view, each pixel's lobe on its mirrored view direction.
run eval_view_glossy "$pbgi" eval --view cornell --mode glossy --lobes phong -o "$dir/evg" \
  --points 30000 --width 32 --height 24 --rays 128 --exact
[ -s "$dir/evg/pbgi_msa0.03_res12_lobe.png" ] && [ -s "$dir/evg/view.json" ] && ok ||
  fail "eval --view --mode glossy wrote no image or view.json"
grep -q '"mode": "glossy"' "$dir/evg/view.json" && ok || fail "view.json is not glossy"
refuse eval_glossy_view_two "one lobe setting" "$pbgi" eval --view cornell --mode glossy \
  -o "$dir/egv"
refuse eval_glossy_bad "ggx_roughness" "$pbgi" eval cornell --mode glossy -o "$dir/egb" \
  --points 1000 --lobes ggx --ggx-roughnesses 1.5
# eval --view: the reference, PBGI and error images and the figures, for a small view.
run eval_view "$pbgi" eval --view cornell -o "$dir/eval_view" --points 30000 --width 48 \
  --height 32 --rays 256
for f in reference.png pbgi_msa0.03_res12_cos.png error_msa0.03_res12_cos.png view.json \
  pbgi_msa0.03_res12_cos_shared_s8_t0.05.png shaded_msa0.03_res12_cos_shared_s8_t0.05.png; do
  [ -s "$dir/eval_view/$f" ] && ok || fail "eval --view wrote no $f"
done
grep -q '"mode": "shared"' "$dir/eval_view/view.json" && ok || fail "view.json lacks the shared row"
# eval --view --db: the database of the run above, shaded again without a build; another
# scene's database is refused.
run eval_view_db "$pbgi" eval --view cornell -o "$dir/eval_view_db" --db "$dir/eval_view/cornell.pbgi" \
  --width 48 --height 32 --rays 64 --exact
grep -q "not rebuilt" "$dir/eval_view_db.err" && [ ! -e "$dir/eval_view_db/cornell.pbgi" ] && ok ||
  fail "eval --view --db built a database"
grep -q '"mode": "exact"' "$dir/eval_view_db/view.json" && ok || fail "eval --view --db wrote no rows"
refuse eval_view_db_other "built from another scene|scene" "$pbgi" eval --view city \
  -o "$dir/eval_view_db2" --db "$dir/eval_view/cornell.pbgi" --width 48 --height 32 --rays 64
refuse eval_db_not_view "for --view" "$pbgi" eval cornell -o "$dir/eval_db_nv" \
  --db "$dir/eval_view/cornell.pbgi"
# eval --view --window: only the window's pixels are shaded and compared; --dump-receivers
# lists them, each row's error its PBGI value less its reference.
run eval_view_window "$pbgi" eval --view cornell -o "$dir/eval_win" --points 30000 --width 48 \
  --height 32 --rays 64 --exact --window 8,8,16,8 --dump-receivers "$dir/win.csv"
awk -F, 'NR > 1 {n++; if ($1 < 8 || $1 >= 24 || $2 < 8 || $2 >= 16) bad++;
  d = $11 - ($10 - $9); if (d < -2e-6 || d > 2e-6) bad++}
  END {exit !(n > 0 && n <= 128 && bad == 0)}' "$dir/win.csv" && ok ||
  fail "eval --view --window dumped pixels outside the window or wrong errors"
refuse eval_view_bad_window "X,Y,WIDTH,HEIGHT" "$pbgi" eval --view cornell -o "$dir/eval_win" \
  --points 30000 --width 48 --height 32 --rays 64 --exact --window 40,8,16,8
# The reference mode: demo --exact shades every receiver on its own; the default shares.
run demo_exact "$pbgi" demo -o "$dir/demo_exact" --scene cornell --points 40000 --width 48 \
  --height 32 --memory 64M --cache 64M --exact
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

# --- issue 18: no silent wrong results, point clouds from other tools, safe commands ---------
check() { python3 "$here/ply_check.py" "$@"; }
fixtures="$here/fixtures"
assimp_ply=/usr/share/assimp/models/PLY  # Debian's assimp-testmodels (scripts/install-deps.sh)
json() { python3 -c "import json, sys; j = json.load(open(sys.argv[1])); print($2)" "$1"; }

# `pbgi build` without --threads pipelines on every core (docs/format.md, "Session 11: build
# throughput from a PLY"), and says so in its statistics.
cores=$(getconf _NPROCESSORS_ONLN)
built_threads=$(json "$dir/stats.json" "j['threads']")
[ "$built_threads" = "$cores" ] && ok || fail "build without --threads ran $built_threads threads on $cores cores"

# An output that is an input is refused before anything is opened, and the input stays intact.
cp "$dir/c.ply" "$dir/same.ply"
refuse same_output "is the input" "$pbgi" shade "$dir/c.pbgi" --receivers "$dir/same.ply" -o "$dir/same.ply"
cmp -s "$dir/c.ply" "$dir/same.ply" && ok || fail "shade -o INPUT changed its input"
refuse exr_for_points "PLY" "$pbgi" shade "$dir/c.pbgi" --receivers "$dir/c.ply" -o "$dir/x.exr"
[ ! -e "$dir/x.exr" ] && ok || fail "shade --receivers -o x.exr left a file"
ls "$dir"/*.tmp-* >/dev/null 2>&1 && fail "temporary outputs left behind: $(ls "$dir"/*.tmp-*)" || ok
# Glossy views are shaded glossy, not the irradiance image.
run view_glossy "$pbgi" shade "$dir/c.pbgi" --scene cornell --seed 3 -o "$dir/glossy.exr" \
  --width 32 --height 24 --raster-res 8 --mode glossy
run view_irr "$pbgi" shade "$dir/c.pbgi" --scene cornell --seed 3 -o "$dir/irr.exr" \
  --width 32 --height 24 --raster-res 8 --mode irradiance --cut plain
cmp -s "$dir/glossy.exr" "$dir/irr.exr" && fail "the glossy view is the irradiance view" || ok
# A view of another scene than the database's is refused, unless asked for.
refuse wrong_scene "built from scene 'cornell'" "$pbgi" shade "$dir/c.pbgi" --scene city -o "$dir/w.png" --width 16 --height 16
run any_scene "$pbgi" shade "$dir/c.pbgi" --scene city -o "$dir/w.png" --width 16 --height 16 --raster-res 8 --any-scene
# Outputs carry uchar red green blue beside the float results.
check props "$dir/shaded.ply" irradiance_r red green blue && ok || fail "shaded.ply lacks its colours"

# Receivers: no radius needed; rx ry rz reflections are used by glossy; invalid ones named.
printf 'ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty float rx\nproperty float ry\nproperty float rz\nend_header\n0.5 0.5 0.02 0 0 1 0 0 1\n0.5 0.5 0.02 0 0 1 0.9 0 0.43589\n0.5 0.5 0.02 0 0 1 0 0 1\n' > "$dir/refl.ply"
run glossy_refl "$pbgi" shade "$dir/c.pbgi" --receivers "$dir/refl.ply" -o "$dir/refl_out.ply" --mode glossy
python3 - "$dir/refl_out.ply" "$here" <<'PY' && ok || fail "glossy ignores the receivers' rx ry rz"
import sys; sys.path.insert(0, sys.argv[2]); import ply_check as p
n, v = p.read(sys.argv[1]); g = [r[n.index("glossy_g")] for r in v]
sys.exit(0 if g[0] == g[2] and abs(g[0] - g[1]) > 0.1 * g[0] > 0 else 1)
PY
printf 'ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\nend_header\n0.5 0.5 0.02 0 0 1\n0.5 0.5 0.02 0 0 0\n0.4 0.5 0.02 0 0 1\n' > "$dir/bad_rx.ply"
refuse bad_receiver "receiver 1 .*zero normal" "$pbgi" shade "$dir/c.pbgi" --receivers "$dir/bad_rx.ply" -o "$dir/bad_out.ply"
[ ! -e "$dir/bad_out.ply" ] && ok || fail "a failed shade left bad_out.ply"
run bad_skip "$pbgi" shade "$dir/c.pbgi" --receivers "$dir/bad_rx.ply" -o "$dir/bad_out.ply" --invalid skip
check count "$dir/bad_out.ply" 2 && ok || fail "--invalid skip did not write 2 receivers"
run bad_zero "$pbgi" shade "$dir/c.pbgi" --receivers "$dir/bad_rx.ply" -o "$dir/bad_out.ply" --invalid zero
check count "$dir/bad_out.ply" 3 && ok || fail "--invalid zero did not write 3 receivers"

# Point clouds written by Open3D (tests/tools/fixtures/make_open3d_fixtures.py): normals but no
# radius, and neither. The radius comes from the density: 1500 points on a unit box and a sphere
# of radius 0.2 (area 6.50) spread sqrt(6.50 / (pi 1500)) = 0.0371 apart.
run o3d_normals "$pbgi" build "$fixtures/open3d_normals.ply" -o "$dir/o3n.pbgi" --memory 64M
grep -q "estimating each surfel's radius" "$dir/o3d_normals.err" && ok || fail "build does not say it estimates radii"
run o3d_export "$pbgi" export "$dir/o3n.pbgi" -o "$dir/o3n.ply"
check count "$dir/o3n.ply" 1500 && ok || fail "export of o3n.pbgi does not hold 1500 surfels"
check radius "$dir/o3n.ply" 0.030 0.045 >/dev/null && ok || fail "estimated radius: $(check radius "$dir/o3n.ply" 0 1)"
check normals "$dir/o3n.ply" "$fixtures/open3d_normals.ply" 0.9999 1.0 >/dev/null && ok ||
  fail "build changed the given normals: $(check normals "$dir/o3n.ply" "$fixtures/open3d_normals.ply" 0.9999 1.0)"
run o3d_xyz "$pbgi" build "$fixtures/open3d_xyz.ply" -o "$dir/o3x.pbgi" --memory 64M
grep -q "no normals" "$dir/o3d_xyz.err" && ok || fail "build does not say it estimates normals"
run o3d_xyz_export "$pbgi" export "$dir/o3x.pbgi" -o "$dir/o3x.ply"
# PCA normals agree with the true ones (up to sign) within 25 degrees for most points; those
# near the box's edges and on the coarse sphere mix two planes.
check normals "$dir/o3x.ply" "$fixtures/open3d_normals.ply" 0.9 0.8 >/dev/null && ok ||
  fail "estimated normals: $(check normals "$dir/o3x.ply" "$fixtures/open3d_normals.ply" 0.9 0.8)"
run o3d_radius "$pbgi" build "$fixtures/open3d_xyz.ply" -o "$dir/o3r.pbgi" --memory 64M --radius 0.02
run o3d_radius_export "$pbgi" export "$dir/o3r.pbgi" -o "$dir/o3r.ply"
check radius "$dir/o3r.ply" 0.0199 0.0201 >/dev/null && ok || fail "--radius 0.02 not used"
run o3d_receivers "$pbgi" shade "$dir/o3n.pbgi" --receivers "$fixtures/open3d_normals.ply" -o "$dir/o3_shaded.ply" --raster-res 8
check count "$dir/o3_shaded.ply" 1500 && ok || fail "receivers without radius not all shaded"
# Point clouds written by PCL (tests/tools/fixtures/make_pcl_fixtures.sh): an empty face element
# and a camera element after the vertices; binary with normals (voxel-averaged, not unit length)
# and curvature, and ascii with positions only. 6739 points on an area of 6.50 spread
# sqrt(6.50 / (pi 6739)) = 0.0175 apart.
run pcl_normals "$pbgi" build "$fixtures/pcl_normals.ply" -o "$dir/pn.pbgi" --memory 64M
grep -q "estimating each surfel's radius" "$dir/pcl_normals.err" && ok || fail "build (PCL) does not say it estimates radii"
run pcl_export "$pbgi" export "$dir/pn.pbgi" -o "$dir/pn.ply"
check count "$dir/pn.ply" 6739 && ok || fail "export of pn.pbgi does not hold 6739 surfels"
check radius "$dir/pn.ply" 0.015 0.020 >/dev/null && ok || fail "estimated radius (PCL): $(check radius "$dir/pn.ply" 0 1)"
check normals "$dir/pn.ply" "$fixtures/pcl_normals.ply" 0.9999 1.0 >/dev/null && ok ||
  fail "build changed PCL's normals: $(check normals "$dir/pn.ply" "$fixtures/pcl_normals.ply" 0.9999 1.0)"
run pcl_xyz "$pbgi" build "$fixtures/pcl_xyz.ply" -o "$dir/px.pbgi" --memory 64M
grep -q "no normals" "$dir/pcl_xyz.err" && ok || fail "build (PCL xyz) does not say it estimates normals"
run pcl_xyz_export "$pbgi" export "$dir/px.pbgi" -o "$dir/px.ply"
check normals "$dir/px.ply" "$fixtures/pcl_normals.ply" 0.9 0.8 >/dev/null && ok ||
  fail "estimated normals (PCL): $(check normals "$dir/px.ply" "$fixtures/pcl_normals.ply" 0.9 0.8)"
# Every receiver of the closed room is enclosed: occlusion 1 (PBGI within 5%).
run pcl_receivers "$pbgi" shade "$dir/pn.pbgi" --receivers "$fixtures/pcl_normals.ply" -o "$dir/pn_shaded.ply" --raster-res 8
check count "$dir/pn_shaded.ply" 6739 && ok || fail "PCL receivers not all shaded"
check mean "$dir/pn_shaded.ply" occlusion 0.95 1.0 >/dev/null && ok ||
  fail "PCL room: $(check mean "$dir/pn_shaded.ply" occlusion 0 1)"
# Big-endian: the same points read alike.
check big_endian "$fixtures/open3d_normals.ply" "$dir/o3_be.ply" && ok || fail "could not write a big-endian copy"
run be_build "$pbgi" build "$dir/o3_be.ply" -o "$dir/o3be.pbgi" --memory 64M
run be_info "$pbgi" info "$dir/o3be.pbgi" --json
run le_info "$pbgi" info "$dir/o3n.pbgi" --json
[ "$(json "$dir/be_info.out" 'j["bounds"], j["point_count"]')" = "$(json "$dir/le_info.out" 'j["bounds"], j["point_count"]')" ] &&
  ok || fail "big-endian and little-endian copies built different databases"
# A free-text header line without 'comment' (Blender's, in assimp-testmodels) is read and noted.
run freetext "$pbgi" info "$assimp_ply/Wuson.ply"
grep -q "11184" "$dir/freetext.out" && grep -q "free text" "$dir/freetext.out" && ok ||
  fail "info on Wuson.ply: $(head -c 300 "$dir/freetext.out")"
# Meshes: --up y turns Y-up files upright; point clouds are sent to build.
run up_y "$pbgi" import "$assimp_ply/Wuson.ply" -n 5k -o "$dir/wy.ply" --up y
run up_y_info "$pbgi" info "$dir/wy.ply" --json
awk -v z="$(json "$dir/up_y_info.out" 'j["bounds"]["hi"][2]')" 'BEGIN {exit !(z > 1.4 && z < 1.55)}' && ok ||
  fail "--up y: the top is not the file's y maximum 1.515"
refuse import_cloud "pbgi build" "$pbgi" import "$assimp_ply/pond.0.ply" -n 1k -o "$dir/pond.ply"
grep -q "orientation: 54 components: 1 closed" "$dir/up_y.err" && ok ||
  fail "import did not report its orientation: $(grep orientation "$dir/up_y.err")"
# Its open parts are marked thin, so their surfels are two-sided in the PLY it writes
# (regression import_drops_two_sided: the flag was set by the sampler, not written).
check props "$dir/wy.ply" two_sided && ok || fail "import wrote no two_sided property"
check mean "$dir/wy.ply" two_sided 0.001 1.0 >/dev/null && ok || fail "import: no surfel two-sided: $(check mean "$dir/wy.ply" two_sided 0 1)"
# Views of a Y-up mesh: --up y on shade matches the import; without it the mismatch names the
# up axis (regression mesh_mismatch_names_up: both descriptions read alike) and the fix.
# Each side of a thin part is baked with its own light: the PLY carries back_r back_g back_b, the
# database keeps them (pbgi info: back_radiance), and an export carries them on to a rebuild.
check props "$dir/wy.ply" back_r back_g back_b && ok || fail "import wrote no back radiance"
check mean "$dir/wy.ply" back_g 0.0001 10 >/dev/null && ok ||
  fail "import: no back radiance: $(check mean "$dir/wy.ply" back_g 0 10)"
run up_y_build "$pbgi" build "$dir/wy.ply" -o "$dir/wy.pbgi" --memory 64M
run back_info "$pbgi" info "$dir/wy.pbgi" --json
[ "$(json "$dir/back_info.out" 'j["back_radiance"]')" = "True" ] && ok ||
  fail "the database of a mesh with thin parts keeps no back radiance"
run back_export "$pbgi" export "$dir/wy.pbgi" -o "$dir/wye.ply"
check props "$dir/wye.ply" back_r back_g back_b && ok || fail "export wrote no back radiance"
run back_rebuild "$pbgi" build "$dir/wye.ply" -o "$dir/wye.pbgi" --memory 64M
run back_rebuild_info "$pbgi" info "$dir/wye.pbgi" --json
[ "$(json "$dir/back_rebuild_info.out" 'j["back_radiance"]')" = "True" ] && ok ||
  fail "a rebuild from the export lost the back radiance"
refuse view_up_mismatch "up: database y, view z.*--up y" \
  "$pbgi" shade "$dir/wy.pbgi" --scene "$assimp_ply/Wuson.ply" -o "$dir/wy.png" --mode occlusion \
  --width 16 --height 16
run view_up_y "$pbgi" shade "$dir/wy.pbgi" --scene "$assimp_ply/Wuson.ply" --up y -o "$dir/wy.png" \
  --mode occlusion --width 16 --height 16
[ -s "$dir/wy.png" ] && ok || fail "shade --up y wrote no image"
# eval --mode irradiance of a mesh file: lit by a white sky as `pbgi import` lights it, and said
# so; before, a mesh had no lights in eval, every irradiance was 0 and compared as exact
# (regression mesh_irradiance_compares_zeros).
run eval_mesh_irr "$pbgi" eval "$assimp_ply/Wuson.ply" --mode irradiance -o "$dir/ewi" \
  --points 20000 --receivers 30 --rays 256 --ray-sweep 16 --solid-angles 0.03 --raster-res 8
grep -q "brings no lights: lit by a white sky" "$dir/eval_mesh_irr.err" && ok ||
  fail "eval of a mesh does not say how it is lit: $(head -c 300 "$dir/eval_mesh_irr.err")"
mean=$(grep -o 'of the mean irradiance [0-9.e+-]*' "$dir/eval_mesh_irr.out" | awk '{print $NF}')
awk -v m="$mean" 'BEGIN {exit !(m > 0.02)}' && ok ||
  fail "eval of a mesh: mean irradiance '$mean', not above 0.02"
# eval --view --db of an imported mesh: lit by the lights recorded in the database, as shade is.
run eval_view_db_lights "$pbgi" eval "$assimp_ply/Wuson.ply" --up y --view --db "$dir/wy.pbgi" \
  --mode irradiance -o "$dir/evdb" --width 16 --height 16 --rays 16 --exact
grep -q "lit by the lights recorded in the database" "$dir/eval_view_db_lights.err" && ok ||
  fail "eval --view --db of a mesh ignores the recorded lights: $(head -c 300 "$dir/eval_view_db_lights.err")"
refuse eval_bad_sun "sun: zero direction" "$pbgi" eval "$assimp_ply/Wuson.ply" \
  --mode irradiance -o "$dir/ewb" --points 2000 --receivers 4 --rays 16 --sun 0,0,0
# spider.obj has 4 triangles wound against their neighbours: --orient none keeps them.
spider="$(dirname "$assimp_ply")/OBJ/spider.obj"
run orient_none "$pbgi" import "$spider" -n 5k -o "$dir/sn.ply" --orient none
run orient_none_build "$pbgi" build "$dir/sn.ply" -o "$dir/sn.pbgi" --memory 64M
refuse view_orient_mismatch "orient: database none, view auto.*--orient none" \
  "$pbgi" shade "$dir/sn.pbgi" --scene "$spider" -o "$dir/sn.png" --mode occlusion \
  --width 16 --height 16
run view_orient_none "$pbgi" shade "$dir/sn.pbgi" --scene "$spider" --orient none \
  -o "$dir/sn.png" --mode occlusion --width 16 --height 16
run eval_view_up_y "$pbgi" eval --view "$assimp_ply/Wuson.ply" --up y -o "$dir/wuson-view" \
  --mode occlusion --points 5000 --width 16 --height 16 --rays 64 --exact
grep -q "orientation:" "$dir/eval_view_up_y.out" && ok || fail "eval --view did not report orientation"

# build -o: refuses other files and an existing database without --force.
mkdir -p "$dir/notadb" && touch "$dir/notadb/keep"
refuse build_nondb "not a database" "$pbgi" build "$dir/c.ply" -o "$dir/notadb" --memory 64M
[ -e "$dir/notadb/keep" ] && ok || fail "build -o removed another directory's files"
cp -r "$dir/c.pbgi" "$dir/c2.pbgi"
refuse build_exists "database already.*force" "$pbgi" build "$dir/c.ply" -o "$dir/c2.pbgi" --memory 64M
run build_force "$pbgi" build "$dir/o3_be.ply" -o "$dir/c2.pbgi" --memory 64M --force
run force_info "$pbgi" info "$dir/c2.pbgi" --json
[ "$(json "$dir/force_info.out" 'j["point_count"]')" = "1500" ] && ok || fail "--force did not replace the database"
# Sizes and budgets.
run count_k "$pbgi" generate cornell -n 2.5k -o "$dir/k.ply" --seed 3 --keep-hidden
check count "$dir/k.ply" 2500 && ok || fail "-n 2.5k did not make 2500 points"
refuse unitless "no unit" "$pbgi" build "$dir/k.ply" -o "$dir/k.pbgi" --memory 100
# One spelling and help on every option.
PBGI_LIST_OPTIONS=1 "$pbgi" > "$dir/options.txt"
awk -F'\t' '$3 == "" {print $1, $2}' "$dir/options.txt" > "$dir/undocumented.txt"
[ ! -s "$dir/undocumented.txt" ] && ok || fail "options without help: $(tr '\n' ' ' < "$dir/undocumented.txt")"
awk -F'\t' '$2 == "--out" || $2 == "--threads" && $3 !~ /0: all cores/ {print $1, $2}' "$dir/options.txt" > "$dir/bad_o.txt"
[ ! -s "$dir/bad_o.txt" ] && [ "$(grep -c '	--output	' "$dir/options.txt")" -ge 7 ] && ok ||
  fail "not one spelling of --output and --threads: $(tr '\n' ' ' < "$dir/bad_o.txt")"
# Progress: done / total, rate, ETA per line, then a summary.
PBGI_PROGRESS=lines PBGI_PROGRESS_SECONDS=0 "$pbgi" shade "$dir/o3n.pbgi" --receivers \
  "$fixtures/open3d_normals.ply" -o "$dir/o3_shaded.ply" --raster-res 8 --chunk 500 >/dev/null 2>"$dir/progress.err"
grep -qE '^shade: [0-9]+ / 1500 receivers \([0-9.]+%\), .*receivers/s, ETA' "$dir/progress.err" && ok ||
  fail "no progress lines: $(head -c 300 "$dir/progress.err")"
# A closed pipe on stderr (`2>&1 | head`) ends the job like ^C: no temporary file is left.
mkdir -p "$dir/pipe"
PBGI_PROGRESS=lines PBGI_PROGRESS_SECONDS=0 "$pbgi" shade "$dir/c.pbgi" --receivers "$dir/c.ply" \
  -o "$dir/pipe/s.ply" --raster-res 8 --chunk 2k 2>&1 >/dev/null | head -n 1 >/dev/null
ls "$dir/pipe"/*.tmp-* >/dev/null 2>&1 && fail "a closed pipe left $(ls "$dir/pipe")" || ok
# Every long job ends with a summary: count, time, rate.
for job in "generate:generate" "build:build" "shade_points:shade" "demo:demo: shade" "eval:eval: sweeps" \
           "eval_view:eval --view: build" "up_y:import" "o3d_export:export"; do
  grep -qE "^${job#*:}: [0-9]+ [a-z ]+ in [0-9.]+ s \(" "$dir/${job%%:*}.err" && ok ||
    fail "${job%%:*} printed no summary '${job#*:}: N ... in T s (rate)': $(tail -n 2 "$dir/${job%%:*}.err")"
done
# info on a PLY, and typed JSON with provenance.
run info_ply "$pbgi" info "$dir/c.ply" --json
[ "$(json "$dir/info_ply.out" 'j["vertex_count"], j["provenance"]["scene.name"], j["provenance"]["scene.seed"]')" = "30000 cornell 3" ] &&
  ok || fail "info --json on c.ply: $(head -c 300 "$dir/info_ply.out")"
[ "$(json "$dir/info.out" 'j["provenance"]["input"].endswith("c.ply"), j["provenance"]["scene.name"]')" = "True cornell" ] &&
  ok || fail "info --json on a database lacks its input"
# query: --cut and the shaded values; the plain cut gathers more clusters.
run query_cos "$pbgi" query "$dir/c.pbgi" --at 0.5,0.5,0.02 --normal 0,0,1 --json
run query_plain "$pbgi" query "$dir/c.pbgi" --at 0.5,0.5,0.02 --normal 0,0,1 --json --cut plain
python3 - "$dir/query_cos.out" "$dir/query_plain.out" <<'PY' && ok || fail "query --cut: $(head -c 300 "$dir/query_plain.out")"
import json, sys
c, p = (json.load(open(f)) for f in sys.argv[1:3])
s = c["shaded"]
sys.exit(0 if 0 < s["occlusion"] <= 1 and c["gathered"]["clusters"] < p["gathered"]["clusters"] else 1)
PY

finish
