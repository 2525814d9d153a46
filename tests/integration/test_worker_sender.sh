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

"$worker" --domain $domain --id slow --inject-publish-delay 800 --log-every 1 >"$dir/slow.log" 2>&1 & slow_pid=$!
pids+=($slow_pid)
"$worker" --domain $domain --id fast --log-every 1 >"$dir/fast.log" 2>&1 & fast_pid=$!
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

# Simulation went on during a write: a line with two batches' steps beyond what was written, in
# back-pressure, with most of the interval spent waiting for a free buffer.
ahead=$(sed -n 's/.* backpressure: [0-9]* steps\/s (collect: .*backpressure \([0-9]*\)%.*; sender: publish [0-9]*%), \([0-9]*\) batches sent, \([0-9]*\) env steps,.*/\1 \2 \3/p' "$dir/slow.log" |
  awk -v batch=$batch '$3 >= ($2 + 2) * batch && $1 >= 50 { n++ } END { print n + 0 }')
[ "$ahead" -ge 2 ] ||
  fail "the slowed worker never collected two batches beyond those written while in back-pressure ($ahead lines):
$(grep -E 'steps/s' "$dir/slow.log" | head -8)"

summary="$dir/run/summary.txt"
[ -s "$summary" ] || fail "no summary: $(tail -5 "$dir/learner.log")"
grep -Eq "^batches +ok [0-9]+, lost 0, duplicate 0, invalid 0" "$summary" ||
  fail "batches lost, duplicate or invalid: $(grep '^batches' "$summary")"
for w in slow fast; do
  sent=$(sed -n 's/.*finished: \([0-9]*\) batches sent (sequence 0\.\.\([0-9]*\)).*/\1/p' "$dir/$w.log")
  [ -n "$sent" ] && [ "$sent" -ge 5 ] || fail "worker $w sent ${sent:-no} batches (5 or more expected)"
  line=$(grep -E "^worker +$w session [0-9]+:" "$summary")
  [[ "$line" =~ received\ ([0-9]+)\ of\ sequence\ 0\.\.([0-9]+),\ lost\ 0,\ duplicate\ 0,\ invalid\ 0,\ stream\ closed ]] ||
    fail "worker $w's stream at the learner: '$line'"
  [ "${BASH_REMATCH[1]:-x}" = "${sent:-y}" ] && [ "${BASH_REMATCH[2]:-x}" = "$((${sent:-0} - 1))" ] ||
    fail "worker $w sent $sent batches, the learner: '$line'"
done
echo "slowed worker: $ahead lines two batches ahead of its writes; $(grep -E '^worker ' "$summary" | tr -s ' ' | paste -sd ';')"
farm_test_end "a slowed worker simulates ahead of its writes; every batch once, in order, streams closed"
