#!/usr/bin/env bash
# Installs what is missing, builds, and runs every test (unit, integration, learning) with ctest.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$ROOT/deploy/install-deps.sh"
"$ROOT/deploy/build.sh"
cd "${FARM_BUILD_DIR:-$ROOT/build}"
if [ $# -gt 0 ]; then
  exec ctest --output-on-failure --timeout 900 "$@"
fi
# The unit tests are short and share nothing: as many at a time as there are cores. The others
# start processes and bound how long they take, so they run one at a time.
rc=0
ctest --output-on-failure --timeout 900 -L '^unit$' -j "$(nproc)" || rc=1
ctest --output-on-failure --timeout 900 -LE '^unit$' || rc=1
exit $rc
