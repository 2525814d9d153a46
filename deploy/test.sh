#!/usr/bin/env bash
# Installs what is missing, builds, and runs every test (unit, integration, learning) with ctest.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$ROOT/deploy/install-deps.sh"
"$ROOT/deploy/build.sh"
cd "${FARM_BUILD_DIR:-$ROOT/build}"
ctest --output-on-failure --timeout 900 "$@"
