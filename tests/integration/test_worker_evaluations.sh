#!/usr/bin/env bash
# Evaluations run on the workers, asked for and answered over the bus.
#   1. A learner alone: its final evaluation finds no worker, says so and the learner ends.
#   2. A learner and two workers: each evaluation is split into two parts, one asked of each
#      worker, answered (asked == answered, lost 0, invalid 0) and reported as one; then the worker
#      holding a part is SIGKILLed: the part is counted lost, asked again of the other worker and
#      answered there, and the run finishes. Its workers run at worker.nice 7: every thread of
#      each (the evaluation thread, made after the join, too) at that nice value.
#   tests/integration/test_worker_evaluations.sh LEARNER WORKER
set -uo pipefail
learner=$(readlink -f "$1") worker=$(readlink -f "$2")
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init worker-evals 181

# config NAME EPISODES MAX_SECONDS
config() {
  cat >"$dir/$1.txtpb" <<CFG
experiment_id: "it_worker_evals_$1"
task { name: "pendulum" }
sac { hidden: 32 hidden: 32 learning_starts: 100 batch_size: 64 publish_every_updates: 5 }
worker { envs_per_worker: 4 steps_per_batch: 25 max_batches_per_version: 4 nice: 7 }
# Evaluations of 8,000 episodes, 4,000 a worker, take 2-7 s a part here: long enough to kill one
# while it holds a part (parts of 750 took 0.2-0.8 s here, and the kill once came after the answer).
eval { episodes: $2 every_seconds: 2 final_episodes: 20 answer_timeout_seconds: 60 }
worker_timeout_seconds: 2
checkpoint_every_seconds: 600
log_every_seconds: 1
stop { max_seconds: $3 }
CFG
}

# 1. No worker at all: the final evaluation is not waited for beyond the worker timeout.
config alone 10 2
timeout 120 "$learner" --config "$dir/alone.txtpb" --run-dir "$dir/alone" --domain $domain >"$dir/alone.log" 2>&1
rc=$?
[ $rc = 0 ] || fail "alone: learner exited $rc: $(tail -5 "$dir/alone.log")"
# It gave up after worker_timeout_seconds (2 s) without a worker, far below the 60 s answer timeout.
waited=$(sed -n 's/.*final evaluation of policy v0 not answered (no live worker took it) after \([0-9]*\) s.*/\1/p' "$dir/alone.log")
[ -n "$waited" ] && [ "$waited" -le 10 ] || fail "alone: the final evaluation was waited for '${waited:-?}' s without workers"
grep -q "waits for a live worker (none now)" "$dir/alone.log" || fail "alone: no line saying the evaluation waits"
grep -q "^evaluations       asked 0, answered 0, lost 0, invalid 0" "$dir/alone/summary.txt" ||
  fail "alone: summary: $(grep evaluations "$dir/alone/summary.txt")"

# 2. Two workers, one killed while it evaluates.
config two 8000 25
"$learner" --config "$dir/two.txtpb" --run-dir "$dir/two" --domain $domain >"$dir/two.log" 2>&1 & lp=$!
pids+=($lp)
"$worker" --domain $domain --id ev-1 >"$dir/ev-1.log" 2>&1 & w1=$!
"$worker" --domain $domain --id ev-2 >"$dir/ev-2.log" 2>&1 & w2=$!
pids+=($w1 $w2)
# Both workers answer before the kill.
for w in ev-1 ev-2; do
  wait_text "$dir/two.log" "answered by $w " 60 || fail "no evaluation answered by $w within 60 s"
done
# worker.nice: each worker's threads, its evaluation thread among them, at nice 7 (this shell's own
# nice, if higher, is what they keep); the join line says so.
base=$(nice)
want=$((base > 7 ? base : 7))
for w in ev-1:$w1 ev-2:$w2; do
  pid=${w#*:} nices=""
  for t in /proc/$pid/task/*/stat; do nices+="$(sed 's/.*) //' "$t" 2>/dev/null | awk '{print $17}') "; done
  n=$(wc -w <<<"$nices")
  [ "$n" -ge 3 ] && [ -z "$(tr ' ' '\n' <<<"$nices" | grep -v "^$want\$" | grep -v '^$')" ] ||
    fail "${w%%:*}: its $n threads' nice values are '$nices', not all $want (worker.nice 7)"
  grep -q "joined experiment .*, nice 7 (worker.nice) on [0-9]* threads" "$dir/${w%%:*}.log" ||
    fail "${w%%:*}: the join line does not give its nice: $(grep joined "$dir/${w%%:*}.log")"
done
# Each evaluation is split over the two workers (eval.min_episodes_per_worker: 4 by default): 4,000
# episodes each, asked of both, reported once as 8,000.
wait_text "$dir/two.log" "complete: 8000 episodes from 2 workers" 60 ||
  fail "no evaluation reported as 8000 episodes from 2 workers: $(grep 'asked of worker' "$dir/two.log" | head -4)"
first=$(grep "asked of worker" "$dir/two.log" | grep -A1 -m1 "4000 episodes, part 1 of 2, 8000 in all, #0-3999 of seed ")
grep -q "(eval, policy v[0-9]*, 4000 episodes, part 2 of 2, 8000 in all, #4000-7999 of seed [0-9]*) asked of worker ev-" \
  <<<"$first" && [ "$(grep -o 'asked of worker ev-[12]' <<<"$first" | sort -u | wc -l)" = 2 ] ||
  fail "no evaluation asked as two parts of 4000 of the two workers: $first"
# Both parts carry the evaluation's seed (episode k of it is reset from that seed and k on any
# worker), so the split runs the episodes one worker would run whole.
[ "$(grep -o ' of seed [0-9]*)' <<<"$first" | sort -u | wc -l)" = 1 ] ||
  fail "the two parts of one evaluation carry different seeds: $first"
# The next request: its worker is killed as soon as it says it has it.
asked=$(grep -c "asked of worker" "$dir/two.log")
for _ in $(seq 150); do [ "$(grep -c "asked of worker" "$dir/two.log")" -gt "$asked" ] && break; sleep 0.1; done
line=$(grep "asked of worker" "$dir/two.log" | sed -n "$((asked + 1))p")
id=$(sed -n 's/.*evaluation \([0-9]*\) (eval.*/\1/p' <<<"$line") victim=$(sed -n 's/.*asked of worker \(ev-[12]\)$/\1/p' <<<"$line")
[ -n "$id" ] && [ -n "$victim" ] || fail "no new evaluation request to kill a worker on: '$line'"
if [ -n "$id" ] && [ -n "$victim" ]; then
  wait_text "$dir/$victim.log" "evaluation request $id:" 20 || fail "$victim never said it has request $id"
  # Before the kill every evaluation asked was answered.
  grep -q "evals asked \([0-9]*\) answered \1 lost 0 invalid 0" "$dir/two.log" ||
    fail "no progress line with asked == answered, lost 0, invalid 0 before the kill"
  if [ "$victim" = ev-1 ]; then kill -9 $w1; other=ev-2; else kill -9 $w2; other=ev-1; fi
  echo "killed $victim holding evaluation $id"
  grep -q "evaluation $id answered" "$dir/$victim.log" && fail "$victim answered $id before the kill: the test proves nothing"
fi
wait $lp; rc=$?
[ $rc = 0 ] || fail "learner exited $rc: $(tail -5 "$dir/two.log")"
grep "evaluation\|eval:" "$dir/two.log" | tail -12
if [ -n "${id:-}" ] && [ -n "${victim:-}" ]; then
  grep -q "evaluation $id (policy v[0-9]*) asked of $victim lost: its worker is no longer live; asked again" \
    "$dir/two.log" || fail "request $id not counted lost when $victim died"
  # The second try is the first one asked after the loss (it may wait for a live worker first).
  retry=$(sed -n "/evaluation $id (policy v[0-9]*) asked of $victim lost/,\$p" "$dir/two.log" | grep -m1 "second try, #[^)]*) asked of" |
    sed -n 's/.*evaluation \([0-9]*\) (eval, policy v[0-9]*, [0-9]* episodes[^)]*, second try, #[^)]*) asked of worker \(ev-[12]\)$/\1 \2/p')
  [ "${retry#* }" = "$other" ] || fail "the lost request was not asked again of $other: '$retry'"
  grep -q "evaluation ${retry%% *} answered by $other " "$dir/two.log" || fail "the second try was not answered"
fi
summary=$(grep "^evaluations" "$dir/two/summary.txt")
echo "$summary"
read -r a b l i <<<"$(sed -n 's/^evaluations *asked \([0-9]*\), answered \([0-9]*\), lost \([0-9]*\), invalid \([0-9]*\).*/\1 \2 \3 \4/p' <<<"$summary")"
[ -n "${l:-}" ] && [ "$l" -ge 1 ] && [ "${i:-}" = 0 ] && [ "$a" = $((b + l)) ] || fail "summary counts: $summary"
# Each part counted lost has its eval_lost event. All were asked of the killed worker: the one it
# held, and any the learner asked of it before it saw the worker gone (worker_timeout_seconds 2).
lost_events=$(events "$dir/two" eval_lost)
[ "$(grep -c . <<<"$lost_events")" = "${l:-}" ] || fail "summary says $l lost, events say: $lost_events"
if [ -n "${id:-}" ] && [ -n "${victim:-}" ]; then
  grep -q "\"request_id\":$id,.*\"worker_id\":\"$victim\"" <<<"$lost_events" ||
    fail "no eval_lost event for request $id of $victim: $lost_events"
  [ -z "$(grep -v "\"worker_id\":\"$victim\"" <<<"$lost_events")" ] ||
    fail "a part asked of another worker than $victim was lost: $lost_events"
fi
grep -q "^final eval return  *-\?[0-9]" "$dir/two/summary.txt" || fail "no final eval return: $(cat "$dir/two/summary.txt")"
farm_test_end "evaluations answered by workers; a killed worker's request lost and answered by the other"
