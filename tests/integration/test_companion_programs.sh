#!/usr/bin/env bash
# Programs that start other programs find them next to themselves first, and say which paths they
# tried when a program is missing: bench_scale copied into a folder with farm-worker beside it
# runs that farm-worker and delivers; a --worker-bin that is not there, or a worker that exits at
# once, is reported within seconds (not after 60 s of waiting per worker count).
#   tests/integration/test_companion_programs.sh BENCH_SCALE WORKER
set -uo pipefail
bench_scale=$(readlink -f "$1") worker=$(readlink -f "$2")
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init companion 53

# 1. A copied folder: bench_scale and farm-worker side by side, started from elsewhere.
mkdir -p "$dir/bin"
cp "$bench_scale" "$worker" "$dir/bin/"
(cd / && timeout 60 "$dir/bin/bench_scale" --workers 1 --envs 4 --seconds 1 --warmup 1 --domain $domain \
   --log-dir "$dir/logs1") >"$dir/copied.txt" 2>&1; rc=$?
cat "$dir/copied.txt"
grep -q "^bench_scale: workers $dir/bin/farm-worker$" "$dir/copied.txt" ||
  fail "the copied bench_scale did not take the farm-worker beside it"
[ $rc = 0 ] && grep -Eq "^ +1 +[0-9]+" "$dir/copied.txt" || fail "the copied bench_scale exited $rc"

# 2. A --worker-bin that is not there: named at once.
start=$(date +%s)
out=$(timeout 60 "$bench_scale" --workers 1 --worker-bin "$dir/nowhere/farm-worker" --domain $domain 2>&1); rc=$?
took=$(( $(date +%s) - start ))
[ $rc = 2 ] && grep -q -- "--worker-bin $dir/nowhere/farm-worker: no executable file there" <<<"$out" ||
  fail "missing --worker-bin: rc $rc, '$out'"
[ $took -le 10 ] || fail "missing --worker-bin took $took s to report"

# 3. A worker program that exits at once: reported with its exit code, within seconds.
start=$(date +%s)
out=$(timeout 60 "$bench_scale" --workers 1 --worker-bin /bin/false --domain $domain --log-dir "$dir/logs3" 2>&1); rc=$?
took=$(( $(date +%s) - start ))
[ $rc != 0 ] && grep -q "worker w0 (/bin/false) exited with code 1 before delivering" <<<"$out" ||
  fail "worker exiting at once: rc $rc, '$out'"
[ $took -le 15 ] || fail "a worker exiting at once took $took s to report"

farm_test_end
