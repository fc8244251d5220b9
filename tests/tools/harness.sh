# The command tests' common start and end, sourced with the test's own arguments:
#   source "$(dirname "$0")/harness.sh" "$@"    (then the checks, each ending in ok or fail)
#   finish                                      (the last line: the summary and exit status)
# Sets pbgi (the binary, $1) and dir (the scratch directory, $2, emptied).
set -uo pipefail
pbgi="$1"
dir="$2"
rm -rf "$dir"
mkdir -p "$dir"
failures=0
passes=0
ok() { passes=$((passes + 1)); }
fail() { echo "FAIL: $*" >&2; failures=$((failures + 1)); }
# The summary line; its status is 0 when nothing failed.
finish() {
  echo "$(basename "$0" .sh): $passes passed, $failures failed"
  [ "$failures" -eq 0 ]
}
