#!/usr/bin/env bash
# A worker simulates while it publishes: its writes are slowed (--inject-publish-delay, each write
# of a batch waits 0.8 s) and it must still collect ahead of what it has written, two batches
# ahead (one being written, one waiting: both buffers with the sender) and say that it is in
# back-pressure; a worker that published on its collect loop would never have collected more
# than the batches it had written. A second worker beside it is not slowed. The learner (SAC,
# before learning starts, so it only takes batches) ends on its time limit: every batch each
# worker says it sent arrived once and in order, and each stream was closed.
#   tests/integration/test_worker_sender.sh LEARNER WORKER
set -uo pipefail
learner=$(readlink -f "$1") worker=$(readlink -f "$2")
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init sender 131

envs=4 steps=25
batch=$((envs * steps))
cat >"$dir/sac.txtpb" <<CFG
experiment_id: "it_sender"
task { name: "pendulum" }
sac { hidden: 16 hidden: 16 learning_starts: 1000000 buffer_size: 1000000 }
worker { envs_per_worker: $envs steps_per_batch: $steps max_batches_per_version: 100000 }
eval { episodes: 2 every_seconds: 600 final_episodes: 2 }
checkpoint_every_seconds: 600
log_every_seconds: 2
stop { max_seconds: 14 }
CFG

# wait_exit PID SECONDS: the process's exit status, or 124 (and the process killed) after SECONDS.
wait_exit() {
  for _ in $(seq $(($2 * 5))); do
    kill -0 "$1" 2>/dev/null || { wait "$1"; return $?; }
    sleep 0.2
  done
  kill -9 "$1" 2>/dev/null
  wait "$1" 2>/dev/null
  return 124
}

"$worker" --domain $domain --id slow --inject-publish-delay 800 --log-every 1 --events "$dir/slow.jsonl" \
  >"$dir/slow.log" 2>&1 & slow_pid=$!
pids+=($slow_pid)
"$worker" --domain $domain --id fast --log-every 1 --events "$dir/fast.jsonl" >"$dir/fast.log" 2>&1 & fast_pid=$!
pids+=($fast_pid)
"$learner" --config "$dir/sac.txtpb" --run-dir "$dir/run" --domain $domain >"$dir/learner.log" 2>&1 & learner_pid=$!
pids+=($learner_pid)

wait_exit $learner_pid 90; rc=$?
[ $rc = 0 ] || fail "learner exit $rc: $(tail -5 "$dir/learner.log")"
for w in slow fast; do
  eval "p=\$${w}_pid"
  wait_exit "$p" 30; rc=$?
  [ $rc = 0 ] || fail "worker $w exit $rc: $(tail -5 "$dir/$w.log")"
done

# Simulation went on during a write: a progress event of the slowed worker with two batches' steps
# beyond what was written, in back-pressure, with half the interval or more spent waiting for a free
# buffer.
ahead=$(python3 -c '
import json, sys
batch = int(sys.argv[2])
n = 0
for line in open(sys.argv[1]):
    e = json.loads(line)
    if e.get("event") == "progress" and e["state"] == "backpressure" and e["backpressure"] is not None:
        n += e["env_steps"] >= (e["batches_sent"] + 2) * batch and e["backpressure"] >= 0.495
print(n)
' "$dir/slow.jsonl" "$batch" 2>/dev/null || echo 0)
[ "$ahead" -ge 2 ] ||
  fail "the slowed worker never collected two batches beyond those written while in back-pressure ($ahead events):
$(worker_events "$dir/slow.jsonl" progress | head -8)"

summary_of "$dir/run" 's["reason"]' >/dev/null || fail "no summary event: $(tail -5 "$dir/learner.log")"
summary_batches_whole "$dir/run" 0 || fail "batches lost, duplicate or invalid: $(events "$dir/run" summary)"
for w in slow fast; do
  sent=$(event_of "$dir/$w.jsonl" finished 'e["batches_sent"]')
  [ -n "$sent" ] && [ "$sent" -ge 5 ] || fail "worker $w sent ${sent:-no} batches (5 or more expected)"
  line=$(summary_of "$dir/run" 'w("'"$w"'")')
  [ "$(summary_of "$dir/run" '[(f["received"], f["last_sequence"], f["lost"], f["duplicate"], f["invalid"], f["closed"]) for f in w("'"$w"'")] == [('"${sent:-0}, $((${sent:-0} - 1))"', 0, 0, 0, True)]')" = true ] ||
    fail "worker $w sent $sent batches, the learner: '$line'"
done
echo "slowed worker: $ahead lines two batches ahead of its writes; $(summary_of "$dir/run" 's["streams"]')"
farm_test_end "a slowed worker simulates ahead of its writes; every batch once, in order, streams closed"
