#!/usr/bin/env bash
# I/O errors under `pbgi build` (issue 17): io_fault_shim.so fails the k-th write, fsync or
# rename under the scratch directory with EIO or ENOSPC (once, from then on, or as a short
# write), for every k up to the number of such calls a clean build makes. Every run must end
# with exit 1 and a message naming the store, and leave the previous database byte for byte,
# with no data.mdb.tmp or lock left; only a failure after the new store was renamed into place
# may leave the new one, and then the message says so and the new store verifies.
# Usage: io_fault_test.sh PBGI_BINARY SHIM_SO SCRATCH_DIR
set -uo pipefail
pbgi="$1"
shim="$2"
dir="$3"
rm -rf "$dir"
mkdir -p "$dir"
failures=0
runs=0
fail() { echo "FAIL: $*" >&2; failures=$((failures + 1)); }

"$pbgi" generate cornell -n 3000 -o "$dir/old.ply" --seed 1 >/dev/null 2>&1 || { echo "generate failed"; exit 1; }
"$pbgi" generate cornell -n 5000 -o "$dir/new.ply" --seed 2 >/dev/null 2>&1 || { echo "generate failed"; exit 1; }
mkdir -p "$dir/base"
"$pbgi" build "$dir/old.ply" -o "$dir/base/db" --channels occlusion --page-size 4080 >/dev/null 2>&1 ||
  { echo "base build failed"; exit 1; }
old_sum=$(md5sum < "$dir/base/db/data.mdb")

# One build of new.ply over a copy of the old database, under the shim.
attempt() {  # OPS ERRNO STICKY SHORT K
  rm -rf "$dir/work"
  cp -a "$dir/base" "$dir/work"
  env LD_PRELOAD="$shim" PBGI_FAULT_PATH="$dir/work" PBGI_FAULT_OPS="$1" PBGI_FAULT_ERRNO="$2" \
    PBGI_FAULT_STICKY="$3" PBGI_FAULT_SHORT="$4" PBGI_FAULT_AT="$5" \
    PBGI_FAULT_COUNT_FILE="$dir/count" \
    "$pbgi" build "$dir/new.ply" -o "$dir/work/db" --channels occlusion --page-size 4080 \
    >"$dir/out" 2>"$dir/err"
}

check() {  # what RC
  local what="$1" rc="$2"
  runs=$((runs + 1))
  if [ "$rc" -eq 0 ]; then
    fail "$what: exit 0 although the fault was injected"
    return
  fi
  if ! grep -q "$dir/work/db" "$dir/err"; then
    fail "$what: the message does not name the store: $(head -c 300 "$dir/err")"
  fi
  if ! grep -qiE "I/O error|disk full|no space|input/output|cut short|failed" "$dir/err"; then
    fail "$what: the message does not say what failed: $(head -c 300 "$dir/err")"
  fi
  if grep -q "is in place" "$dir/err"; then
    # Only after the rename: the new store, whole.
    if ! "$pbgi" verify "$dir/work/db" >/dev/null 2>&1; then fail "$what: the new store does not verify"; fi
    grep -q "$new_points" <("$pbgi" info --json "$dir/work/db") || fail "$what: the store in place is not the new one"
  else
    [ "$(md5sum < "$dir/work/db/data.mdb")" = "$old_sum" ] || fail "$what: the previous database changed"
  fi
  local left
  left=$(ls "$dir/work/db")
  [ "$left" = "data.mdb" ] || fail "$what: the store directory holds: $(echo $left)"
  ls "$dir/work" | grep -qv '^db$' && fail "$what: left in the parent: $(ls "$dir/work")"
}

for config in "write EIO 0 0" "write ENOSPC 1 0" "write ENOSPC 1 1" "fsync EIO 0 0" \
              "fsync ENOSPC 1 0" "rename EIO 0 0" "rename ENOSPC 0 0"; do
  set -- $config
  attempt "$1" "$2" "$3" "$4" 0
  if [ $? -ne 0 ]; then fail "$config: the clean build under the shim failed: $(head -c 300 "$dir/err")"; continue; fi
  calls=$(cat "$dir/count")
  new_points=$("$pbgi" info --json "$dir/work/db" | grep -o '"point_count": [0-9]*')
  [ "$calls" -gt 0 ] || fail "$config: the shim counted no calls"
  for k in $(seq 1 "$calls"); do
    attempt "$1" "$2" "$3" "$4" "$k"
    check "$config, call $k of $calls" $?
  done
  echo "io_fault_test: $config: $calls calls, each failed once: done"
done
echo "io_fault_test: $runs faulty builds, $failures failures"
[ "$failures" -eq 0 ]
