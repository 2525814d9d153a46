#!/usr/bin/env bash
# Whoever writes first does not own a worker's stream, before or after a resume. A thief reads the
# heartbeats of the experiment and, for each worker session it hears of, writes well-formed batches
# under that worker's id and session numbered from 0 (farm_intruder --steal-streams 1); it starts
# before the worker, which beats for a while (waiting for weights) before its first batch. The
# learner is stopped with SIGINT while the worker trains and started again with --resume; the thief
# goes on all along. The real worker's stream must be taken whole from its own participant: in the
# summary, its one session received every number it sent, lost 0, duplicate 0, invalid 0, stream
# closed; the thief's batches were refused (invalid > 0 in all).
#   tests/integration/test_stream_thief.sh LEARNER WORKER INTRUDER SOURCE_DIR
set -uo pipefail
learner=$(readlink -f "$1") worker=$(readlink -f "$2") intruder=$(readlink -f "$3") src=$(readlink -f "$4")
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init stream-thief 191

pendulum_config "$src" it_thief "max_seconds: 16" "$dir/thief.txtpb"
"$learner" --config "$dir/thief.txtpb" --run-dir "$dir/run" --domain $domain >"$dir/learner.log" 2>&1 & lp=$!; pids+=($lp)
"$intruder" --domain $domain --experiment it_thief --id thief --seconds 45 --steal-streams 1 --events "$dir/thief.jsonl" \
  >"$dir/thief.log" 2>&1 &
tp=$!; pids+=($tp)
wait_has_event "$dir/thief.jsonl" joined 15 || fail "the thief did not start: $(cat "$dir/thief.log")"
sleep 1
"$worker" --domain $domain --id tw --envs 4 --events "$dir/worker.jsonl" >"$dir/worker.log" 2>&1 & wp=$!; pids+=($wp)
for _ in $(seq 150); do [ "$(batches_ok "$dir/run")" -gt 20 ] && break; sleep 0.2; done
[ "$(batches_ok "$dir/run")" -gt 20 ] || fail "the worker's batches were not taken: batches_ok $(batches_ok "$dir/run")"
wait_has_event "$dir/thief.jsonl" stealing 15 worker_id='"tw"' ||
  fail "the thief heard no session of tw: $(cat "$dir/thief.log")"
kill -INT $lp
wait_pid $lp 30; rc=$?
[ $rc = 130 ] || fail "the learner stopped with SIGINT exited with $rc, not 130 (124: still running 30 s later): $(tail -3 "$dir/learner.log")"
"$learner" --config "$dir/thief.txtpb" --run-dir "$dir/run" --domain $domain --resume >"$dir/resumed.log" 2>&1 &
lp=$!; pids+=($lp)
wait_pid $lp 60; rc=$?
[ $rc = 0 ] || fail "the resumed learner exited with $rc (124: still running 60 s later): $(tail -5 "$dir/resumed.log")"
wait_pid $wp 20; rc=$?
[ $rc = 0 ] || fail "the worker exited with $rc (124: still running 20 s after its learner): $(tail -3 "$dir/worker.log")"
kill $tp 2>/dev/null

sent=$(event_of "$dir/worker.jsonl" finished 'e["batches_sent"]')
streams=$(summary_of "$dir/run" 'w("tw")')
[ "$(summary_of "$dir/run" 'len(w("tw"))')" = 1 ] || fail "tw has not one session in the summary: $streams"
[ "$(summary_of "$dir/run" '[(f["received"], f["last_sequence"], f["lost"], f["duplicate"], f["invalid"], f["closed"]) for f in w("tw")] == [('"${sent:-0}, $((${sent:-0} - 1))"', 0, 0, 0, True)]')" = true ] ||
  fail "the worker sent $sent batches; the learner's account: $streams"
invalid=$(summary_of "$dir/run" 's["batches_invalid"]')
[ "${invalid:-0}" -gt 0 ] || fail "no batch of the thief was refused, the test shows nothing: $(events "$dir/run" summary)"
first=$(events "$dir/run" refusal | grep -c "whose heartbeats announced it")
farm_test_end "tw's $sent batches all taken across the resume, $invalid of the thief's refused ($first refusal event(s) of a thief's first batch)"
