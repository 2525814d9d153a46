#!/usr/bin/env bash
# Builds the fuzz targets with clang (libFuzzer + AddressSanitizer + UBSan) and runs each for a
# bounded time. Exit status non-zero on any crash, leak or sanitizer finding; the crashing input
# is kept in the build folder.
#   tests/fuzz/run.sh [SECONDS_PER_TARGET] [BUILD_DIR]
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
SECONDS_PER_TARGET="${1:-30}"
B="${2:-$ROOT/build-fuzz}"
command -v clang++ >/dev/null || { echo "fuzz: clang++ missing (deploy/install-deps.sh installs it)" >&2; exit 1; }
mkdir -p "$B"
SAN="-fsanitize=fuzzer-no-link,address,undefined -fno-sanitize-recover=undefined -g -O1"
cmake -S "$ROOT" -B "$B" -G Ninja -DFARM_FUZZ=ON -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++ \
  -DCMAKE_CXX_FLAGS="$SAN" -DCMAKE_C_FLAGS="$SAN" -DCMAKE_EXE_LINKER_FLAGS="-fsanitize=address,undefined" > "$B/configure.log" 2>&1 \
  || { cat "$B/configure.log"; exit 1; }
ninja -C "$B" fuzz_batch fuzz_config
mkdir -p "$B/corpus/batch" "$B/corpus/config" "$B/findings"
cp "$ROOT"/deploy/configs/*.txtpb "$B/corpus/config/"
for t in batch config; do
  echo "fuzz: fuzz_$t for ${SECONDS_PER_TARGET}s"
  rc=0
  ( cd "$B/findings" && "$B/tests/fuzz/fuzz_$t" -max_total_time="$SECONDS_PER_TARGET" -timeout=10 \
      -rss_limit_mb=2048 -max_len=4096 -print_final_stats=1 "$B/corpus/$t" ) > "$B/fuzz_$t.log" 2>&1 || rc=$?
  tail -n 12 "$B/fuzz_$t.log"
  if [ "$rc" -ne 0 ]; then
    grep -m1 -A30 "ERROR\|runtime error\|abort" "$B/fuzz_$t.log" || true
    echo "fuzz: fuzz_$t found a problem (exit $rc); log $B/fuzz_$t.log, inputs kept in $B/findings" >&2
    exit 1
  fi
done
echo "fuzz: no crash, leak or sanitizer finding"
