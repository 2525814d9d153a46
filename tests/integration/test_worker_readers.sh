#!/usr/bin/env bash
# A worker's readers take nothing larger than an experiment allows. A learner (pendulum) and one
# worker train; a participant that is not the learner then publishes a spec, weights and an
# evaluation request (to a worker id no one has) of 200 MiB each. The worker runs on: its peak
# memory stays within 100 MiB of what it was before them, and its batches keep arriving, none
# lost or invalid.
#   tests/integration/test_worker_readers.sh LEARNER WORKER INTRUDER SOURCE_DIR
set -uo pipefail
learner=$(readlink -f "$1") worker=$(readlink -f "$2") intruder=$(readlink -f "$3") src=$(readlink -f "$4")
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init worker-readers 141

start_pendulum_pair "$src" "$learner" "$worker" it_readers "max_seconds: 25" rw
peak_before=$(peak_kb $wp)
"$intruder" --domain $domain --experiment it_readers --id big --seconds 4 --big-to-workers 200 >"$dir/intruder.log" 2>&1 ||
  fail "the intruder did not run: $(tail -2 "$dir/intruder.log")"
kill -0 $wp 2>/dev/null || fail "the worker ended after the large samples: $(tail -3 "$dir/worker.log")"
peak_after=$(peak_kb $wp)
[ -n "$peak_after" ] && [ "$peak_after" -lt $((peak_before + 102400)) ] ||
  fail "the worker's peak memory went from ${peak_before} kB to ${peak_after} kB"
during=$(batches_ok "$dir/run")
[ "$during" -gt "$before" ] || fail "no batch arrived during the attack: $before before, $during after"
wait $lp || fail "the learner exited with $?: $(tail -3 "$dir/learner.log")"
summary_batches_whole "$dir/run" 0 || fail "batches lost or invalid: $(events "$dir/run" summary)"
farm_test_end "worker peak ${peak_before} kB before, ${peak_after} kB after; batches_ok $before, $during; $(tail -1 "$dir/intruder.log")"
