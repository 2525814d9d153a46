#!/usr/bin/env bash
# A participant removal in the learner's name, from the network, does not stop the farm. While a
# pendulum learner trains on one worker's batches, a program with no DDS library sends raw UDP
# SPDP DATA(p[UD]) messages, the message a participant sends as it leaves, naming the learner's GUID
# prefix, to every discovery port of the domain every 50 ms (farm_intruder --forge-removal 1). The
# worker must go on sending: the env steps/s the learner accepts (its learner.csv) with the attack
# running are at least 0.9 of those with it paused, over five rounds of 3 s paused (SIGSTOP) and
# 3 s running (alternate_attack in lib.sh), and the run ends with nothing lost or invalid.
#   tests/integration/test_forged_removal.sh LEARNER WORKER INTRUDER SOURCE_DIR
set -uo pipefail
learner=$(readlink -f "$1") worker=$(readlink -f "$2") intruder=$(readlink -f "$3") src=$(readlink -f "$4")
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init forged-removal 173

start_pendulum_pair "$src" "$learner" "$worker" it_removal "max_seconds: 52" rw
sleep 2
"$intruder" --domain $domain --experiment it_removal --id remover --seconds 40 --forge-removal 1 \
  --events "$dir/intruder.jsonl" >"$dir/intruder.log" 2>&1 & ip=$!; pids+=($ip)
# Its record (an events file, read as a worker's is) says whom the removals name before the first.
wait_worker_event "$dir/intruder.jsonl" naming_learner 20 ||
  fail "the intruder found no learner to name: $(cat "$dir/intruder.log")"
alternate_attack $ip "$dir/run" env_steps 5 3
wait $ip || fail "the intruder failed: $(cat "$dir/intruder.log")"
[ "$(event_of "$dir/intruder.jsonl" removals 'e["sent"] > 0')" = true ] ||
  fail "the intruder sent no removal, the test shows nothing: $(cat "$dir/intruder.log")"
before=$quiet_rate during=$attack_rate
echo "env steps/s with the attack paused $before, running $during"
awk -v b="$before" -v d="$during" 'BEGIN { exit !(b > 0 && d >= 0.9 * b) }' ||
  fail "env steps/s fell from $before to $during during the forged removals: $(grep -c 'waiting_for_learner\|learner' "$dir/worker.log") worker lines on its learner"

wait $lp; lrc=$?
[ $lrc = 0 ] || fail "the learner exited with $lrc: $(tail -5 "$dir/learner.log")"
summary_batches_whole "$dir/run" 0 || fail "batches lost or invalid: $(events "$dir/run" summary)"
farm_test_end "env steps/s $before before the forged removals, $during during them"
