#!/usr/bin/env bash
# Installs every Debian 12 package that Coherent PBGI needs to build, test and run.
# Idempotent: when everything is present it does nothing (no apt-get update, no network).
set -euo pipefail

PACKAGES=(
  # toolchain (clang and its runtime libraries: the clang build and libFuzzer's fuzz targets)
  g++ make cmake ninja-build pkg-config ca-certificates clang libclang-rt-14-dev
  # libraries
  liblmdb-dev lmdb-utils libabsl-dev libglm-dev libzstd-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  libembree-dev libassimp-dev libopenexr-dev libstb-dev libcli11-dev libtbb-dev
  nlohmann-json3-dev
  # build: the k-d tree of the radius and normal estimates (header-only)
  libnanoflann-dev
  # tools: the charts of `pbgi eval` (PLplot and its cairo PNG driver)
  libplplot-dev plplot-driver-cairo
  # the Python module (python/) and its tests, example and progress bars
  python3-dev pybind11-dev python3-numpy python3-pytest python3-matplotlib python3-tqdm
  # tools used by the test suite and the measurements
  time valgrind
  # the CLI test: an independent PLY reader (stdlib only) and the PLY files of assimp-testmodels
  python3 assimp-testmodels
)

missing=()
for p in "${PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  exit 0
fi

if [ "$(id -u)" -ne 0 ]; then
  echo "install-deps: missing packages: ${missing[*]}" >&2
  echo "install-deps: run as root (or with sudo) to install them" >&2
  exit 1
fi

echo "install-deps: installing ${missing[*]}" >&2
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq
apt-get install -y -qq --no-install-recommends "${missing[@]}"
