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
waited=$(event_of "$dir/alone/events.jsonl" eval_not_answered 'int(e["waited_s"]) if e["label"] == "final" and e["worker_id"] == "" else ""')
[ -n "$waited" ] && [ "$waited" -le 10 ] || fail "alone: the final evaluation was waited for '${waited:-?}' s without workers"
events "$dir/alone" eval_waits | grep -qF '"label":"final"' || fail "alone: no event saying the evaluation waits"
[ "$(summary_of "$dir/alone" 's["evals_asked"], s["evals_answered"], s["evals_lost"], s["evals_invalid"]')" = "0 0 0 0" ] ||
  fail "alone: summary: $(events "$dir/alone" summary)"

# 2. Two workers, one killed while it evaluates.
config two 8000 25
run="$dir/two"
"$learner" --config "$dir/two.txtpb" --run-dir "$run" --domain $domain >"$dir/two.log" 2>&1 & lp=$!
pids+=($lp)
"$worker" --domain $domain --id ev-1 --events "$dir/ev-1.jsonl" >"$dir/ev-1.log" 2>&1 & w1=$!
"$worker" --domain $domain --id ev-2 --events "$dir/ev-2.jsonl" >"$dir/ev-2.log" 2>&1 & w2=$!
pids+=($w1 $w2)
# Both workers answer before the kill.
for w in ev-1 ev-2; do
  wait_event "$run" answer 60 "\"worker_id\":\"$w\"" || fail "no evaluation answered by $w within 60 s"
done
# worker.nice: each worker's threads, its evaluation thread among them, at nice 7 (this shell's own
# nice, if higher, is what they keep); its joined event says so.
base=$(nice)
want=$((base > 7 ? base : 7))
for w in ev-1:$w1 ev-2:$w2; do
  pid=${w#*:} nices=""
  for t in /proc/$pid/task/*/stat; do nices+="$(sed 's/.*) //' "$t" 2>/dev/null | awk '{print $17}') "; done
  n=$(wc -w <<<"$nices")
  [ "$n" -ge 3 ] && [ -z "$(tr ' ' '\n' <<<"$nices" | grep -v "^$want\$" | grep -v '^$')" ] ||
    fail "${w%%:*}: its $n threads' nice values are '$nices', not all $want (worker.nice 7)"
  [ "$(event_of "$dir/${w%%:*}.jsonl" joined 'e["nice"]')" = 7 ] ||
    fail "${w%%:*}: the joined event does not give its nice: $(worker_events "$dir/${w%%:*}.jsonl" joined)"
done
# Each evaluation is split over the two workers (eval.min_episodes_per_worker: 4 by default): 4,000
# episodes each, asked of both, reported once as 8,000.
for _ in $(seq 300); do has_event "$run/events.jsonl" evaluation episodes=8000 workers=2 && break; sleep 0.2; done
has_event "$run/events.jsonl" evaluation episodes=8000 workers=2 ||
  fail "no evaluation reported as 8000 episodes from 2 workers: $(events "$run" evaluation | head -4)"
# The first split evaluation's two parts: 4000 episodes each, #0-3999 and #4000-7999 of one seed
# (episode k of it is reset from that seed and k on any worker, so the split runs the episodes one
# worker would run whole), asked of the two workers.
parts=$(python3 -c "$_read_events_py"'
asks = [a for a in read(sys.argv[1], "ask") if a["label"] == "eval" and a["attempt"] == 1]
first = [a for a in asks if a["part"] == 1 and a["parts"] == 2][:1]
first += [a for a in asks if first and a["policy_version"] == first[0]["policy_version"] and a["part"] == 2][:1]
ok = (len(first) == 2 and [(a["episodes"], a["total_episodes"], a["first_episode"]) for a in first]
      == [(4000, 8000, 0), (4000, 8000, 4000)] and first[0]["seed"] == first[1]["seed"]
      and {a["worker_id"] for a in first} == {"ev-1", "ev-2"})
print("ok" if ok else first)
' "$run/events.jsonl" 2>&1)
[ "$parts" = ok ] || fail "no evaluation asked as two parts of 4000 of one seed of the two workers: $parts"
# A request out now (asked, neither answered nor lost): its worker is killed as soon as it says it
# has it.
id="" victim=""
for _ in $(seq 60); do
  read -r id victim < <(python3 -c "$_read_events_py"'
done = {e["request_id"] for kind in ("answer", "eval_lost") for e in read(sys.argv[1], kind)}
out = [a for a in read(sys.argv[1], "ask") if a["label"] == "eval" and a["request_id"] not in done]
print(out[-1]["request_id"], out[-1]["worker_id"]) if out else print()
' "$run/events.jsonl" 2>/dev/null)
  [ -n "${id:-}" ] && break
  sleep 0.25
done
[ -n "${id:-}" ] && [ -n "${victim:-}" ] || fail "no evaluation request out to kill a worker on"
if [ -n "${id:-}" ] && [ -n "${victim:-}" ]; then
  for _ in $(seq 100); do has_event "$dir/$victim.jsonl" eval_request request_id=$id && break; sleep 0.2; done
  has_event "$dir/$victim.jsonl" eval_request request_id=$id || fail "$victim never said it has request $id"
  # Before the kill every evaluation asked was answered.
  events "$run" progress | python3 -c '
import json, sys
sys.exit(not any(e["evals_asked"] == e["evals_answered"] and e["evals_lost"] == 0 and e["evals_invalid"] == 0
                 for e in map(json.loads, sys.stdin)))' ||
    fail "no progress event with asked == answered, lost 0, invalid 0 before the kill"
  if [ "$victim" = ev-1 ]; then kill -9 $w1; other=ev-2; else kill -9 $w2; other=ev-1; fi
  echo "killed $victim holding evaluation $id"
  has_event "$dir/$victim.jsonl" eval_answered request_id=$id &&
    fail "$victim answered $id before the kill: the test proves nothing"
fi
wait $lp; rc=$?
[ $rc = 0 ] || fail "learner exited $rc: $(tail -5 "$dir/two.log")"
events "$run" ask | tail -6
if [ -n "${id:-}" ] && [ -n "${victim:-}" ]; then
  has_event "$run/events.jsonl" eval_lost request_id=$id "worker_id=\"$victim\"" ||
    fail "request $id not counted lost when $victim died: $(events "$run" eval_lost)"
  # The second try is the first part asked again after the loss (it may wait for a live worker first).
  read -r retry retried_of < <(events "$run" ask | python3 -c '
import json, sys
for e in map(json.loads, sys.stdin):
    if e["attempt"] == 2 and e["label"] == "eval":
        print(e["request_id"], e["worker_id"])
        break' 2>/dev/null)
  [ "${retried_of:-}" = "$other" ] || fail "the lost request was not asked again of $other: '${retry:-} ${retried_of:-}'"
  has_event "$run/events.jsonl" answer request_id=${retry:-0} "worker_id=\"$other\"" ||
    fail "the second try was not answered"
fi
read -r a b l i < <(summary_of "$run" 's["evals_asked"], s["evals_answered"], s["evals_lost"], s["evals_invalid"]')
summary="asked ${a:-none}, answered ${b:-none}, lost ${l:-none}, invalid ${i:-none}"
echo "evaluations $summary"
[ -n "${l:-}" ] && [ "$l" -ge 1 ] && [ "${i:-}" = 0 ] && [ "$a" = $((b + l)) ] || fail "summary counts: $summary"
# Each part counted lost has its eval_lost event. All were asked of the killed worker: the one it
# held, and any the learner asked of it before it saw the worker gone (worker_timeout_seconds 2).
lost_events=$(events "$run" eval_lost)
[ "$(grep -c . <<<"$lost_events")" = "${l:-}" ] || fail "summary says $l lost, events say: $lost_events"
if [ -n "${id:-}" ] && [ -n "${victim:-}" ]; then
  grep -q "\"request_id\":$id,.*\"worker_id\":\"$victim\"" <<<"$lost_events" ||
    fail "no eval_lost event for request $id of $victim: $lost_events"
  [ -z "$(grep -v "\"worker_id\":\"$victim\"" <<<"$lost_events")" ] ||
    fail "a part asked of another worker than $victim was lost: $lost_events"
fi
events "$run" evaluation | grep -F '"label":"final"' | grep -q '"mean":-\?[0-9]' ||
  fail "no final evaluation's return: $(events "$run" evaluation)"
farm_test_end "evaluations answered by workers; a killed worker's request lost and answered by the other"
