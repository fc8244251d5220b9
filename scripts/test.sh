#!/usr/bin/env bash
# The whole test suite: installs what is missing, configures and builds in out/ci (warnings are
# errors), then runs every test with ctest. Extra arguments go to ctest (e.g. -R Store).
#   PBGI_SANITIZE=asan|tsan scripts/test.sh   builds in out/ci-asan or out/ci-tsan instead.
# Then (default build, no ctest arguments) it runs the fuzz targets for PBGI_FUZZ_SECONDS (5)
# each under libFuzzer in out/ci-fuzz (clang).
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
  asan)
    flags+=(-DPBGI_ASAN=ON)
    export LSAN_OPTIONS="suppressions=$here/tests/lsan.supp ${LSAN_OPTIONS:-}"
    ;;
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
(cd "$build" && ctest --output-on-failure -j "$jobs" "$@")

# The fuzz targets under libFuzzer (clang, ASan + UBSan), a few seconds each
# (PBGI_FUZZ_SECONDS; 0 skips them). Only the modules they link are built, and every library
# module, so that the library is known to build with clang (-Werror) too (the C API's shared
# library aside: the fuzzers' coverage hooks do not link into it). Not with a
# sanitizer suite (the fuzzers bring their own) nor when ctest was given a test selection.
fuzz_seconds="${PBGI_FUZZ_SECONDS:-5}"
if [ -z "$san" ] && [ $# -eq 0 ] && [ "$fuzz_seconds" != 0 ]; then
  fuzz_build=out/ci-fuzz
  if [ ! -f "$fuzz_build/CMakeCache.txt" ]; then
    CC=clang CXX=clang++ cmake -S . -B "$fuzz_build" "${generator[@]}" \
      -DCMAKE_BUILD_TYPE=RelWithDebInfo -DPBGI_WERROR=ON -DPBGI_FUZZ=ON \
      -DPBGI_BUILD_TESTS=OFF -DPBGI_BUILD_BENCH=OFF -DPBGI_BUILD_TOOLS=OFF -DPBGI_BUILD_PYTHON=OFF \
      -DPBGI_FUZZ_SECONDS="$fuzz_seconds"
  else
    cmake -S . -B "$fuzz_build" -DPBGI_FUZZ_SECONDS="$fuzz_seconds" >/dev/null
  fi
  cmake --build "$fuzz_build" -j "$jobs" --target pbgi_fuzzers pbgi_base pbgi_store pbgi_store_mem \
    pbgi_tree pbgi_build pbgi_scene pbgi_query pbgi_query_testing pbgi_raster pbgi_shade pbgi_capi
  (cd "$fuzz_build" && ctest --output-on-failure -L fuzz)
fi
