#!/usr/bin/env bash
# The whole test suite: installs what is missing, configures and builds in out/ci (warnings are
# errors), then runs every test with ctest. Extra arguments go to ctest (e.g. -R Store).
#   PBGI_SANITIZE=asan|tsan scripts/test.sh   builds in out/ci-asan or out/ci-tsan instead.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$here"
scripts/install-deps.sh

jobs="${PBGI_JOBS:-$(nproc)}"
san="${PBGI_SANITIZE:-}"
build="out/ci${san:+-$san}"
flags=(-DCMAKE_BUILD_TYPE=RelWithDebInfo -DPBGI_WERROR=ON)
case "$san" in
  "") ;;
  asan) flags+=(-DPBGI_ASAN=ON) ;;
  tsan)
    flags+=(-DPBGI_TSAN=ON)
    export TSAN_OPTIONS="suppressions=$here/tests/tsan.supp ${TSAN_OPTIONS:-}"
    ;;
  *) echo "PBGI_SANITIZE must be asan or tsan" >&2; exit 2 ;;
esac
generator=()
command -v ninja >/dev/null && generator=(-G Ninja)
if [ ! -f "$build/CMakeCache.txt" ]; then
  cmake -S . -B "$build" "${generator[@]}" "${flags[@]}"
else
  cmake -S . -B "$build" "${flags[@]}" >/dev/null
fi
cmake --build "$build" -j "$jobs"
cd "$build"
ctest --output-on-failure -j "$jobs" "$@"
