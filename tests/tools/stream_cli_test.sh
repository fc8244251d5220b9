#!/usr/bin/env bash
# Issue 20 through the command: `pbgi generate -o - | pbgi build -` (bounds from the header,
# --bounds, or a spill to --tmp) writes the same node and point pages as a build from the file,
# and `pbgi build --resume` after an interruption writes the same pages as an uninterrupted
# build; clear errors for a truncated stream and for resumes that do not match.
# Pages are compared through LMDB's own mdb_dump (every key and value of the nodes and points
# sub-databases; the meta record holds timings and differs between any two builds).
# Usage: stream_cli_test.sh PBGI_BINARY SCRATCH_DIR
source "$(dirname "$0")/harness.sh" "$@"
refuse() {
  local name="$1" pattern="$2"; shift 2
  if "$@" >"$dir/$name.out" 2>"$dir/$name.err"; then
    fail "$name succeeded but should have failed"
  elif ! grep -qiE "$pattern" "$dir/$name.err"; then
    fail "$name: stderr does not match '$pattern': $(head -c 400 "$dir/$name.err")"
  else ok; fi
}
command -v mdb_dump >/dev/null || { echo "FAIL: mdb_dump (lmdb-utils) is needed" >&2; exit 1; }
# pages DB: a digest of every node and point page.
pages() {
  for s in nodes points; do mdb_dump -s "$s" "$1" | sed '1,/^HEADER=END/d'; done | md5sum | cut -d' ' -f1
}
same() {  # same NAME DB_A DB_B
  local a b
  a=$(pages "$2") b=$(pages "$3")
  [ -n "$a" ] && [ "$a" = "$b" ] && ok || fail "$1: pages of $3 differ from $2 ($a vs $b)"
  "$pbgi" verify "$3" >/dev/null 2>&1 && ok || fail "$1: $3 does not verify"
}
b() { "$pbgi" build "$@" --memory 32M >/dev/null 2>>"$dir/builds.err"; }

# City, hidden samples dropped (the count is known only after sampling), spilled at 32 MiB (3 runs).
"$pbgi" generate city -n 120000 --seed 2 -o "$dir/c.ply" >/dev/null 2>&1 || fail "generate to a file"
"$pbgi" generate city -n 120000 --seed 2 -o - 2>/dev/null >"$dir/s.ply" || fail "generate -o -"
cmp -s <(grep -av '^comment pbgi date' "$dir/c.ply") <(grep -av '^comment pbgi date' "$dir/s.ply") &&
  ok || fail "generate -o - writes other bytes than -o FILE"
grep -aq '^comment pbgi bounds ' "$dir/c.ply" && ok || fail "generate wrote no bounds comment"
b "$dir/c.ply" -o "$dir/file.db" && ok || fail "build from the file: $(tail -n 2 "$dir/builds.err")"
"$pbgi" generate city -n 120000 --seed 2 -o - 2>/dev/null | b - -o "$dir/pipe.db" &&
  ok || fail "generate | build -: $(tail -n 2 "$dir/builds.err")"
same "stdin with header bounds" "$dir/file.db" "$dir/pipe.db"

# Without the bounds line: --bounds (the same box) gives the same pages; no bounds at all spills
# the stream to --tmp and gives the pages of the file without the line.
python3 - "$dir/c.ply" "$dir/nb.ply" <<'PY'
import sys
d = open(sys.argv[1], "rb").read()
i = d.index(b"comment pbgi bounds "); j = d.index(b"\n", i)
open(sys.argv[2], "wb").write(d[:i] + d[j + 1:])
PY
box=$(grep -a -m1 '^comment pbgi bounds ' "$dir/c.ply" | cut -d' ' -f4- | tr ' ' ',')
b - -o "$dir/bounds.db" --bounds="$box" <"$dir/nb.ply" && ok || fail "build - --bounds: $(tail -n 2 "$dir/builds.err")"
same "stdin with --bounds" "$dir/file.db" "$dir/bounds.db"
mkdir -p "$dir/tmp"
cat "$dir/nb.ply" | "$pbgi" build - -o "$dir/spill.db" --memory 32M --tmp "$dir/tmp" \
  >/dev/null 2>"$dir/spill.err" && ok || fail "build - (spilled): $(tail -n 2 "$dir/spill.err")"
grep -q 'copied its' "$dir/spill.err" && ok || fail "the spill was not reported"
[ -z "$(ls -A "$dir/tmp")" ] && ok || fail "the spill left $(ls "$dir/tmp")"
b "$dir/nb.ply" -o "$dir/nbfile.db" && ok || fail "build from nb.ply"
same "spilled stdin" "$dir/nbfile.db" "$dir/spill.db"

# Clear errors: a truncated stream, bounds that do not hold the points, a malformed --bounds.
head -c 3000000 "$dir/c.ply" | refuse truncated 'standard input: truncated at byte offset 3000000' \
  "$pbgi" build - -o "$dir/t.db" --memory 32M
refuse small_bounds 'outside the bounds' "$pbgi" build - -o "$dir/t.db" --memory 32M \
  --bounds=-1,-1,-1,1,1,1 <"$dir/c.ply"
refuse bad_bounds 'six finite numbers' "$pbgi" build - -o "$dir/t.db" --bounds 1,2,3 <"$dir/c.ply"
[ ! -e "$dir/t.db/data.mdb" ] && ok || fail "a failed build left a database"

# Resume: stop after the sort pass (the test hook), resume, compare with the uninterrupted build.
refuse stopped 'run the same command with --resume' \
  "$pbgi" build "$dir/c.ply" -o "$dir/res.db" --memory 32M --tmp "$dir/tmp" --stop-after-sort
ls "$dir"/tmp/pbgi-runs-*/manifest >/dev/null 2>&1 && ok || fail "no manifest kept"
refuse resume_channels 'radiance \(--channels\) differs' \
  "$pbgi" build "$dir/c.ply" -o "$dir/res.db" --memory 32M --tmp "$dir/tmp" --resume --channels occlusion
touch "$dir/c.ply"  # another mtime: another input as far as the manifest knows
refuse resume_touched 'the input differs' \
  "$pbgi" build "$dir/c.ply" -o "$dir/res.db" --memory 32M --tmp "$dir/tmp" --resume
refuse stopped2 'stopped after the sort' \
  "$pbgi" build "$dir/c.ply" -o "$dir/res.db" --memory 32M --tmp "$dir/tmp" --stop-after-sort
"$pbgi" build "$dir/c.ply" -o "$dir/res.db" --memory 32M --tmp "$dir/tmp" --resume \
  >/dev/null 2>"$dir/resume.err" && ok || fail "resume: $(tail -n 2 "$dir/resume.err")"
grep -q 'resumed from' "$dir/resume.err" && ok || fail "the resume was not reported"
same "resumed" "$dir/file.db" "$dir/res.db"
[ -z "$(ls -A "$dir/tmp")" ] && ok || fail "the resumed build left $(ls "$dir/tmp")"
refuse nothing 'nothing to resume' \
  "$pbgi" build "$dir/c.ply" -o "$dir/res2.db" --memory 32M --tmp "$dir/tmp" --resume
# A stream resumes too (its identity is its header, without the date generate stamps). The
# resumed build reads only the header, so generate then ends on a closed pipe: the build's own
# status is what counts.
"$pbgi" generate city -n 120000 --seed 2 -o - 2>/dev/null |
  "$pbgi" build - -o "$dir/sres.db" --memory 32M --tmp "$dir/tmp" --stop-after-sort >/dev/null 2>&1
"$pbgi" generate city -n 120000 --seed 2 -o - 2>/dev/null |
  "$pbgi" build - -o "$dir/sres.db" --memory 32M --tmp "$dir/tmp" --resume >/dev/null \
  2>"$dir/sresume.err"
[ "${PIPESTATUS[1]}" = 0 ] && ok || fail "stream resume: $(tail -n 2 "$dir/sresume.err")"
same "resumed stream" "$dir/file.db" "$dir/sres.db"

finish
