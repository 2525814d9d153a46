#!/usr/bin/env bash
# Configures and builds into ./build (Release): the targets named, else everything. Incremental
# when run again.
#   deploy/build.sh [TARGET ...]      e.g. deploy/build.sh farm-learner farm-worker
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD="${FARM_BUILD_DIR:-$ROOT/build}"
if [ ! -f "$BUILD/build.ninja" ]; then
  cmake -S "$ROOT" -B "$BUILD" -G Ninja -DCMAKE_BUILD_TYPE=Release
fi
# Torch translation units need ~1.5 GB each; two at a time fits a small machine.
targets=()
[ $# -gt 0 ] && targets=(--target "$@")
cmake --build "$BUILD" -j "${FARM_BUILD_JOBS:-$(nproc)}" "${targets[@]}"
