#!/usr/bin/env bash
# Configures and builds everything into ./build (Release). Incremental when run again.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD="${FARM_BUILD_DIR:-$ROOT/build}"
if [ ! -f "$BUILD/build.ninja" ]; then
  cmake -S "$ROOT" -B "$BUILD" -G Ninja -DCMAKE_BUILD_TYPE=Release
fi
# Torch translation units need ~1.5 GB each; two at a time fits a small machine.
cmake --build "$BUILD" -j "${FARM_BUILD_JOBS:-$(nproc)}"
