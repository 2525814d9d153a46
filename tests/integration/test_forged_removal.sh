#!/usr/bin/env bash
# A participant removal in the learner's name, from the network, does not stop the farm. While a
# pendulum learner trains on one worker's batches, a program with no DDS library sends raw UDP
# SPDP DATA(p[UD]) messages, the message a participant sends as it leaves, naming the learner's GUID
# prefix, to every discovery port of the domain every 50 ms (farm_intruder --forge-removal 1). The
# worker must go on sending: the env steps/s the learner accepts during the attack (its learner.csv)
# are at least 0.9 of those just before it, and the run ends with nothing lost or invalid.
#   tests/integration/test_forged_removal.sh LEARNER WORKER INTRUDER SOURCE_DIR
set -uo pipefail
learner=$(readlink -f "$1") worker=$(readlink -f "$2") intruder=$(readlink -f "$3") src=$(readlink -f "$4")
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init forged-removal 173

# elapsed seconds and env steps at the last row of the learner's CSV
steps_row() {
  awk -F, 'NR == 1 { for (i = 1; i <= NF; ++i) { if ($i == "env_steps") s = i; if ($i == "elapsed_s") e = i }; next }
           { le = $e; ls = $s } END { print le + 0, ls + 0 }' "$dir/run/learner.csv" 2>/dev/null
}
rate() { awk -v e1="$1" -v s1="$2" -v e2="$3" -v s2="$4" 'BEGIN { printf "%.0f", (e2 > e1 ? (s2 - s1) / (e2 - e1) : 0) }'; }

start_pendulum_pair "$src" "$learner" "$worker" it_removal "max_seconds: 25" rw
read -r e0 s0 < <(steps_row)
sleep 5
read -r e1 s1 < <(steps_row)
"$intruder" --domain $domain --experiment it_removal --id remover --seconds 9 --forge-removal 1 \
  --events "$dir/intruder.jsonl" >"$dir/intruder.log" 2>&1 & ip=$!; pids+=($ip)
# Its record (an events file, read as a worker's is) says whom the removals name before the first.
wait_worker_event "$dir/intruder.jsonl" naming_learner 20 ||
  fail "the intruder found no learner to name: $(cat "$dir/intruder.log")"
sleep 1
read -r e2 s2 < <(steps_row)
sleep 5
read -r e3 s3 < <(steps_row)
wait $ip || fail "the intruder failed: $(cat "$dir/intruder.log")"
[ "$(event_of "$dir/intruder.jsonl" removals 'e["sent"] > 0')" = true ] ||
  fail "the intruder sent no removal, the test shows nothing: $(cat "$dir/intruder.log")"
before=$(rate "$e0" "$s0" "$e1" "$s1") during=$(rate "$e2" "$s2" "$e3" "$s3")
echo "env steps/s before the attack $before, during it $during"
awk -v b="$before" -v d="$during" 'BEGIN { exit !(b > 0 && d >= 0.9 * b) }' ||
  fail "env steps/s fell from $before to $during during the forged removals: $(grep -c 'waiting_for_learner\|learner' "$dir/worker.log") worker lines on its learner"

wait $lp; lrc=$?
[ $lrc = 0 ] || fail "the learner exited with $lrc: $(tail -5 "$dir/learner.log")"
summary_batches_whole "$dir/run" 0 || fail "batches lost or invalid: $(events "$dir/run" summary)"
farm_test_end "env steps/s $before before the forged removals, $during during them"
