#!/usr/bin/env bash
# Malformed samples end no process. A learner (pendulum) and one worker train; a participant then
# writes samples of every topic whose bytes do not decode (farm_intruder --malformed): a boolean
# byte of 2, counts that claim every byte left, samples cut in half, then every sample mutated
# afresh (fuzz, seeded: --fuzz-seed 7, one sample a topic every 100 ms for 2 s). The learner and the worker run
# on, the worker's batches keep arriving, the malformed batches are counted invalid with a refusal
# event that says why, and the length bomb takes the learner's peak memory no higher.
#   tests/integration/test_malformed.sh LEARNER WORKER INTRUDER SOURCE_DIR
set -uo pipefail
learner=$(readlink -f "$1") worker=$(readlink -f "$2") intruder=$(readlink -f "$3") src=$(readlink -f "$4")
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init malformed 163

# A column of the last row of RUN_DIR/learner.csv.  csv_last RUN_DIR COLUMN
csv_last() {
  awk -F, -v col="$2" 'NR == 1 { for (i = 1; i <= NF; ++i) if ($i == col) c = i; next } c { v = $c } END { print v + 0 }' \
    "$1/learner.csv" 2>/dev/null
}

start_pendulum_pair "$src" "$learner" "$worker" it_malformed "max_seconds: 30" mw
peak_before=$(peak_kb $lp)
for kind in bool length truncate fuzz; do
  "$intruder" --domain $domain --experiment it_malformed --id bad-$kind --seconds 2 --malformed $kind --fuzz-seed 7 \
    >"$dir/intruder-$kind.log" 2>&1 || fail "the intruder ($kind) did not run: $(tail -2 "$dir/intruder-$kind.log")"
  kill -0 $lp 2>/dev/null || fail "the learner ended after malformed samples ($kind): $(tail -3 "$dir/learner.log")"
  kill -0 $wp 2>/dev/null || fail "the worker ended after malformed samples ($kind): $(tail -3 "$dir/worker.log")"
done
peak_after=$(peak_kb $lp)
sleep 2
after=$(batches_ok "$dir/run")
[ "$after" -gt "$before" ] || fail "no batch of the worker arrived after the malformed samples: $before before, $after after"
[ -n "$peak_after" ] && [ "$peak_after" -le $((peak_before * 12 / 10)) ] ||
  fail "the learner's peak memory went from ${peak_before} kB to ${peak_after} kB"
wait $lp || fail "the learner exited with $?: $(tail -3 "$dir/learner.log")"
wait $wp || fail "the worker exited with $?: $(tail -3 "$dir/worker.log")"
invalid=$(csv_last "$dir/run" batches_invalid) lost=$(csv_last "$dir/run" batches_lost)
# Three kinds, one malformed batch every 100 ms for 2 s each: about 60 (and the fuzz's that fail to decode).
[ "$invalid" -ge 30 ] || fail "only $invalid malformed batches were counted invalid"
[ "$lost" -eq 0 ] || fail "$lost of the worker's batches lost"
# (Counted, not grep -q: under pipefail a grep that quits at its first match fails the pipeline.)
[ "$(events "$dir/run" refusal | grep -c '"reason":"malformed"')" -gt 0 ] || fail "no refusal event says malformed"
farm_test_end "batches_ok $before before, $after after; invalid $invalid; learner peak ${peak_before} kB, ${peak_after} kB"
