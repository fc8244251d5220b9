#!/usr/bin/env bash
# Regressions of issue 17 ("Nothing crashes, nothing lies") through the `pbgi` command: outputs
# inside a database directory, two builds to one path, leftovers of a killed build.
# Usage: reliability_cli_test.sh PBGI_BINARY SCRATCH_DIR
source "$(dirname "$0")/harness.sh" "$@"

run() {
  local name="$1"; shift
  if "$@" >"$dir/$name.out" 2>"$dir/$name.err"; then ok; else
    fail "$name exited $? : $(tail -n 3 "$dir/$name.err")"; fi
}
refuse() {
  local name="$1" pattern="$2"; shift 2
  if "$@" >"$dir/$name.out" 2>"$dir/$name.err"; then
    fail "$name succeeded but should have failed"
  elif ! grep -qiE "$pattern" "$dir/$name.err"; then
    fail "$name: stderr does not match '$pattern': $(head -c 300 "$dir/$name.err")"
  else ok; fi
}

run generate "$pbgi" generate cornell -n 20000 -o "$dir/c.ply" --seed 3
run build "$pbgi" build "$dir/c.ply" -o "$dir/db" --memory 64M --channels occlusion
run receivers "$pbgi" generate cornell -n 300 -o "$dir/r.ply" --seed 4
sum_before=$(md5sum < "$dir/db/data.mdb")

# --- outputs inside a database directory (shade -o DB/data.mdb destroyed the database) ---
refuse shade_into_db "database directory" \
  "$pbgi" shade "$dir/db" --receivers "$dir/r.ply" -o "$dir/db/data.mdb" --mode occlusion
refuse shade_onto_db "database directory" \
  "$pbgi" shade "$dir/db" --receivers "$dir/r.ply" -o "$dir/db" --mode occlusion
ln -s "$dir/db" "$dir/link"
refuse shade_through_link "database directory" \
  "$pbgi" shade "$dir/db" --receivers "$dir/r.ply" -o "$dir/link/x.ply" --mode occlusion
refuse view_into_db "database directory" \
  "$pbgi" shade "$dir/db" --scene cornell -o "$dir/db/view.exr" --mode occlusion --width 8 --height 8
refuse generate_into_db "database directory" "$pbgi" generate cornell -n 100 -o "$dir/db/x.ply"
refuse stats_into_db "database directory" \
  "$pbgi" build "$dir/c.ply" -o "$dir/db2" --stats-json "$dir/db/data.mdb"
refuse demo_into_db "database directory" "$pbgi" demo -o "$dir/db" --scene cornell --points 1000
refuse eval_view_into_db "database directory" \
  "$pbgi" eval --view cornell -o "$dir/db/view" --mode occlusion --points 1000 --width 16 --height 16
# Regression (export_into_db): `pbgi export -o` lacked the refusal the other commands have.
refuse export_into_db "database directory" "$pbgi" export "$dir/db" -o "$dir/db/x.ply"
refuse export_through_link "database directory" "$pbgi" export "$dir/db" -o "$dir/link/x.ply"
[ "$(md5sum < "$dir/db/data.mdb")" = "$sum_before" ] && ok || fail "a refused output changed data.mdb"
[ "$(ls "$dir/db")" = "data.mdb" ] && ok || fail "the database directory holds $(ls "$dir/db")"
run verify_after "$pbgi" verify "$dir/db"

# --- shade writes its output beside it and renames: a failed job leaves the previous file ---
run shade_ok "$pbgi" shade "$dir/db" --receivers "$dir/r.ply" -o "$dir/out.ply" --mode occlusion
sum_out=$(md5sum < "$dir/out.ply")
# Receivers whose body is cut short: the job fails after the header.
head -c 2000 "$dir/r.ply" > "$dir/cut.ply"
refuse shade_cut "truncated" \
  "$pbgi" shade "$dir/db" --receivers "$dir/cut.ply" -o "$dir/out.ply" --mode occlusion
[ "$(md5sum < "$dir/out.ply")" = "$sum_out" ] && ok || fail "a failed shade replaced its output"
ls "$dir"/out.ply.tmp-* >/dev/null 2>&1 && fail "a failed shade left its temporary file" || ok

# --- a killed build: info and verify name what it left, the next build removes it ---
run big "$pbgi" generate cornell -n 400000 -o "$dir/big.ply" --seed 5
"$pbgi" build "$dir/big.ply" -o "$dir/db" --force --memory 64M --channels occlusion >/dev/null 2>&1 &
builder=$!
for _ in $(seq 1 200); do
  [ -s "$dir/db/data.mdb.tmp" ] && break
  sleep 0.02
done
# A second build to the same path while the first runs is refused (with --force too: replacing
# a database needs it, issue 18).
refuse second_build "being written by another build" \
  "$pbgi" build "$dir/c.ply" -o "$dir/db" --force --memory 64M --channels occlusion
run info_during "$pbgi" info "$dir/db"
grep -q "is writing" "$dir/info_during.err" && ok || fail "info does not say a build is running"
kill -9 "$builder"
wait "$builder" 2>/dev/null
run info_left "$pbgi" info "$dir/db"
grep -q "left over from a build that did not finish" "$dir/info_left.err" && ok ||
  fail "info does not name the leftover: $(cat "$dir/info_left.err")"
[ "$(md5sum < "$dir/db/data.mdb")" = "$sum_before" ] && ok || fail "the killed build changed data.mdb"
run rebuild "$pbgi" build "$dir/c.ply" -o "$dir/db" --force --memory 64M --channels occlusion
[ "$(ls "$dir/db")" = "data.mdb" ] && ok || fail "after a rebuild the directory holds $(ls "$dir/db")"
# A build that fails on its input leaves no directory behind.
printf 'ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty float radius\nend_header\n' > "$dir/empty.ply"
refuse empty_build "no surfels" "$pbgi" build "$dir/empty.ply" -o "$dir/new/db"
[ -e "$dir/new" ] && fail "a failed build left $dir/new" || ok

# --- parsers: binary-labelled ASCII receivers shaded garbage with exit 0 ---
{
  printf 'ply\nformat binary_little_endian 1.0\nelement vertex 3\n'
  for p in x y z nx ny nz radius; do printf 'property float %s\n' "$p"; done
  printf 'end_header\n0.5 0.5 0.1 0 0 1 0.01\n0.2 0.5 0.1 0 0 1 0.01\n0.7 0.5 0.1 0 0 1 0.01\n'
} > "$dir/mislabelled.ply"
refuse shade_mislabelled "not binary_little_endian" \
  "$pbgi" shade "$dir/db" --receivers "$dir/mislabelled.ply" -o "$dir/m.ply" --mode occlusion

# --- memory budgets that fit the machine (the defaults were OOM-killed in a 128 MiB container) ---
echo 134217728 > "$dir/memory.max"   # a 128 MiB cgroup, 16 MiB of it in use
echo 16777216 > "$dir/memory.current"
export PBGI_CGROUP_MEMORY_LIMIT_FILE="$dir/memory.max" PBGI_CGROUP_MEMORY_USAGE_FILE="$dir/memory.current"
run build_auto "$pbgi" build "$dir/c.ply" -o "$dir/db3" --channels occlusion --stats-json "$dir/auto.json"
mem=$(grep -o '"memory_bytes": [0-9]*' "$dir/auto.json" | grep -o '[0-9]*$')
[ "$mem" -le 58720256 ] && [ "$mem" -ge 28000000 ] && ok ||
  fail "the default --memory in a 128 MiB cgroup is $mem bytes, not half of the 112 MiB left"
grep -q warning "$dir/build_auto.err" && fail "the default budget warned: $(cat "$dir/build_auto.err")" || ok
run build_big "$pbgi" build "$dir/c.ply" -o "$dir/db3" --force --channels occlusion --memory 1G
grep -q "warning: --memory 1.0 GiB is more than this process can use (the memory cgroup allows 128.0 MiB" \
  "$dir/build_big.err" && ok || fail "no warning for --memory 1G in 128 MiB: $(cat "$dir/build_big.err")"
grep -q "try --memory 56M" "$dir/build_big.err" && ok || fail "the warning suggests no budget"
run shade_auto "$pbgi" shade "$dir/db" --receivers "$dir/r.ply" -o "$dir/o2.ply" --mode occlusion
grep -qE "cache (5[0-9]|4[0-9])\.[0-9] MiB" "$dir/shade_auto.out" && ok ||
  fail "the default --cache in 128 MiB: $(grep cache "$dir/shade_auto.out")"
unset PBGI_CGROUP_MEMORY_LIMIT_FILE PBGI_CGROUP_MEMORY_USAGE_FILE
refuse build_tiny "is below the 2[0-9]\.[0-9] MiB this job needs .*give at least --memory [0-9]+K" \
  "$pbgi" build "$dir/c.ply" -o "$dir/db4" --memory 8M
refuse size_overflow "too large a size" "$pbgi" build "$dir/c.ply" -o "$dir/db4" --memory 99999999T
refuse shade_tiny "below the .* this job needs" \
  "$pbgi" shade "$dir/db" --receivers "$dir/r.ply" -o "$dir/o3.ply" --mode occlusion --cache 100K
refuse shade_few_pages "less than the .* threads need" \
  "$pbgi" shade "$dir/db" --receivers "$dir/r.ply" -o "$dir/o3.ply" --mode occlusion --cache 1500K --threads 16
# The receivers in flight come out of the budget: 2 MiB shades 20,000 receivers in chunks.
run many "$pbgi" generate cornell -n 20000 -o "$dir/r20k.ply" --seed 6
run shade_chunks "$pbgi" shade "$dir/db" --receivers "$dir/r20k.ply" -o "$dir/o4.ply" \
  --mode occlusion --cache 2M --threads 1
chunks=$(grep -o "in [0-9]* chunks" "$dir/shade_chunks.out" | grep -o "[0-9]*")
[ "${chunks:-0}" -ge 5 ] && ok || fail "20,000 receivers in a 2 MiB budget went in $chunks chunks"
count=$(grep -a -m1 '^element vertex' "$dir/o4.ply" | awk '{print $3 + 0}')
[ "$count" = "$(grep -a -m1 '^element vertex' "$dir/r20k.ply" | awk '{print $3 + 0}')" ] && ok ||
  fail "chunked shade wrote $count vertices"

finish
