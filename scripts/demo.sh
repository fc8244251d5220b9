#!/usr/bin/env bash
# The main job: installs what is missing, builds the release tree in out/release, then runs
# `pbgi demo` (scene -> surfels -> out-of-core build -> shaded camera view). Extra arguments go
# to `pbgi demo` (e.g. --points 20000000 -o out/demo-big).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$here"
scripts/install-deps.sh
build=out/release
generator=()
command -v ninja >/dev/null && generator=(-G Ninja)
if [ ! -f "$build/CMakeCache.txt" ]; then
  cmake -S . -B "$build" "${generator[@]}" -DCMAKE_BUILD_TYPE=Release -DPBGI_BUILD_TESTS=OFF \
    -DPBGI_BUILD_BENCH=OFF
fi
cmake --build "$build" -j "$(nproc)" --target pbgi_cli
exec "$build/tools/pbgi" demo "$@"
