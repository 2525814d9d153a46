#!/usr/bin/env bash
# A spec after join counts only from the learner the worker joined, and only as join() would take
# it. A worker joins a learner; then participants that are not that learner publish the
# experiment's spec three ways, one after the other: with 2^31 - 1 steps per batch, with
# max_batches_per_version 0, and as the end of the experiment. The worker runs on through all three
# (it refuses another participant's end of the experiment outright, and holds another writer's spec
# back while its learner is on the bus, checking it as at join should that learner leave). The
# learner's record shows it: batches keep arriving during the attack and after it, none lost or
# invalid, and the worker ends (exit 0) with the learner's own end of the run. Then weights: another
# participant republishes the learner's weights a million versions ahead; the worker runs none of
# them (its batches would be of a version the learner never published, refused as invalid).
#   tests/integration/test_spec_trust.sh LEARNER WORKER INTRUDER SOURCE_DIR
set -uo pipefail
learner=$(readlink -f "$1") worker=$(readlink -f "$2") intruder=$(readlink -f "$3") src=$(readlink -f "$4")
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init spec-trust 131

pendulum_config "$src" it_trust "max_seconds: 30" "$dir/trust.txtpb"
"$learner" --config "$dir/trust.txtpb" --run-dir "$dir/run" --domain $domain >"$dir/learner.log" 2>&1 & lp=$!; pids+=($lp)
"$worker" --domain $domain --id tw --envs 4 >"$dir/worker.log" 2>&1 & wp=$!; pids+=($wp)
for _ in $(seq 150); do [ "$(batches_ok "$dir/run")" -gt 0 ] && break; sleep 0.2; done
before=$(batches_ok "$dir/run")
[ "$before" -gt 0 ] || fail "no batch of the worker reached the learner in 30 s: $(tail -5 "$dir/worker.log")"
n=0
for attack in "--spec-steps 2147483647" "--spec-max-batches 0" "--spec-finished 1"; do
  n=$((n + 1))
  # shellcheck disable=SC2086
  "$intruder" --domain $domain --experiment it_trust --id impostor$n --obs 3 --act 1 --seconds 4 --spec-only 1 \
    --spec-config "$dir/trust.txtpb" $attack >"$dir/impostor$n.log" 2>&1 || fail "impostor $n ($attack) did not run"
  kill -0 $wp 2>/dev/null || fail "the worker ended after a spec from another participant ($attack): $(tail -3 "$dir/worker.log")"
done
"$intruder" --domain $domain --experiment it_trust --id forger --seconds 6 --forge-weights 1 \
  --events "$dir/forger.jsonl" >"$dir/forger.log" 2>&1 || fail "the weights forger did not run: $(tail -3 "$dir/forger.log")"
[ "$(event_of "$dir/forger.jsonl" forged_weights 'e["count"] >= 1 and e["readers_matched"] >= 1')" = true ] ||
  fail "the forger wrote no weights a worker read, the test shows nothing: $(cat "$dir/forger.log")"
sleep 2
during=$(batches_ok "$dir/run")
[ "$during" -gt "$before" ] || fail "no batch arrived during the attack: batches_ok $before before it, $during after"

wait $lp; lrc=$?
[ $lrc = 0 ] || fail "the learner exited with $lrc: $(tail -5 "$dir/learner.log")"
for _ in $(seq 100); do kill -0 $wp 2>/dev/null || break; sleep 0.2; done
wait $wp; wrc=$?
[ $wrc = 0 ] || fail "the worker exited with $wrc: $(tail -5 "$dir/worker.log")"
final=$(batches_ok "$dir/run")
[ "$final" -gt "$during" ] || fail "no batch arrived after the attack: batches_ok $during then, $final at the end"
summary_batches_whole "$dir/run" 0 || fail "batches lost or invalid: $(events "$dir/run" summary)"
farm_test_end "batches_ok $before before the attack, $during after it, $final at the end; nothing lost"
