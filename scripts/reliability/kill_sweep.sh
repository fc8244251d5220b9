#!/usr/bin/env bash
# By hand (docs/reliability.md): kills `pbgi build` with SIGKILL at N moments spread over a
# rebuild of an existing database, and checks after each kill that the database is the previous
# one byte for byte (or the new one, complete, when the build had finished), that `pbgi info`
# names what the dead build left, and that the next build removes it.
# Usage: kill_sweep.sh PBGI_BINARY SCRATCH_DIR [N=78] [POINTS=600000]
set -uo pipefail
pbgi="$1"
dir="$2"
n="${3:-78}"
points="${4:-600000}"
rm -rf "$dir"
mkdir -p "$dir"
"$pbgi" generate cornell -n 20000 -o "$dir/old.ply" --seed 1 >/dev/null 2>&1
"$pbgi" generate cornell -n "$points" -o "$dir/new.ply" --seed 2 >/dev/null 2>&1
mkdir -p "$dir/base"
"$pbgi" build "$dir/old.ply" -o "$dir/base/db" >/dev/null 2>&1
old=$(md5sum < "$dir/base/db/data.mdb")
start=$(date +%s.%N)
"$pbgi" build "$dir/new.ply" -o "$dir/time/db" >/dev/null 2>&1
span=$(awk -v a="$start" -v b="$(date +%s.%N)" 'BEGIN { printf "%.3f", b - a }')
previous=0 finished=0 bad=0 named=0 left=0
for i in $(seq 1 "$n"); do
  rm -rf "$dir/work"
  cp -a "$dir/base" "$dir/work"
  delay=$(awk -v s="$span" -v i="$i" -v n="$n" 'BEGIN { printf "%.4f", s * i / n }')
  "$pbgi" build "$dir/new.ply" -o "$dir/work/db" >/dev/null 2>&1 &
  pid=$!
  sleep "$delay"
  kill -9 "$pid" 2>/dev/null
  wait "$pid" 2>/dev/null
  if [ "$(md5sum < "$dir/work/db/data.mdb")" = "$old" ]; then
    previous=$((previous + 1))
  elif "$pbgi" verify "$dir/work/db" >/dev/null 2>&1; then
    finished=$((finished + 1))
  else
    bad=$((bad + 1)); echo "kill $i at ${delay}s: the database is neither the old nor a whole new one"
  fi
  if [ -e "$dir/work/db/data.mdb.tmp" ]; then
    left=$((left + 1))
    "$pbgi" info "$dir/work/db" 2>&1 >/dev/null | grep -q "left over" && named=$((named + 1))
    "$pbgi" build "$dir/old.ply" -o "$dir/work/db" >/dev/null 2>&1
    [ "$(ls "$dir/work/db")" = "data.mdb" ] || { bad=$((bad + 1)); echo "kill $i: the next build left $(ls "$dir/work/db")"; }
  fi
done
echo "kill_sweep: $n kills over ${span}s: $previous left the previous database, $finished a finished new one, $bad anything else; $left left data.mdb.tmp, $named of them named by info, all removed by the next build"
[ "$bad" -eq 0 ] && [ "$named" -eq "$left" ]
