#!/usr/bin/env bash
# Invented live workers do not take the evaluations. A learner (pendulum, an evaluation of 10
# episodes every 3 s, one episode a worker at the least, so a part can go to each of ten workers)
# and one real worker train; a participant keeps 200 invented workers live in the roster with
# heartbeats every second (they run nothing). Evaluations go only to workers whose batches the
# learner has taken: every part is answered by the real worker, none is lost, and the evaluations
# asked during the flood complete. Before the real worker starts, another participant heartbeats
# under its id (the binding pre-emption: session 1, 4 envs, running) and answers every evaluation
# request to that id with episodes of return 0, a return the pendulum cannot give and above the
# run's target of -5; it delivers no batch, so it is asked nothing and its answers to the real
# worker's requests come from another participant than the one asked: no evaluation holds a return
# of 0 and the run ends at its time limit, not at the target.
#   tests/integration/test_invented_roster.sh LEARNER WORKER INTRUDER SOURCE_DIR
set -uo pipefail
learner=$(readlink -f "$1") worker=$(readlink -f "$2") intruder=$(readlink -f "$3") src=$(readlink -f "$4")
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init invented-roster 171

pendulum_config "$src" it_roster "target_eval_return: -5 max_seconds: 24" "$dir/it_roster.txtpb"
sed -i 's/^  every_seconds: 10$/  every_seconds: 3\n  min_episodes_per_worker: 1\n  answer_timeout_seconds: 60/' \
  "$dir/it_roster.txtpb"
grep -q "min_episodes_per_worker: 1" "$dir/it_roster.txtpb" || fail "test set-up: the eval block was not edited"
"$learner" --config "$dir/it_roster.txtpb" --run-dir "$dir/run" --domain $domain >"$dir/learner.log" 2>&1 & lp=$!; pids+=($lp)
"$intruder" --domain $domain --experiment it_roster --id real --heartbeat 1 --deliver 0 --forge-answers 0 \
  --forge-length 200 --seconds 40 >"$dir/preemptor.log" 2>&1 & pids+=($!)
for _ in $(seq 100); do
  events "$dir/run" worker | grep -F '"worker_id":"real"' | grep -cF '"session":1,' >/dev/null && break
  sleep 0.2
done
"$worker" --domain $domain --id real --envs 4 >"$dir/worker.log" 2>&1 & wp=$!; pids+=($wp)
"$intruder" --domain $domain --experiment it_roster --id ghost --seconds 18 --flood-heartbeats 200 --beat-every 1 \
  >"$dir/intruder.log" 2>&1 || fail "the intruder did not run: $(tail -2 "$dir/intruder.log")"
wait $lp || fail "the learner exited with $?: $(tail -3 "$dir/learner.log")"
# From the learner's events: the workers that joined, who answered, what was lost, what completed.
python3 - "$dir/run/events.jsonl" <<'PY' || failed=1
import json, sys
ev = [json.loads(l) for l in open(sys.argv[1])]
joined = {e["worker_id"] for e in ev if e["event"] == "worker" and e.get("change") == "joined"}
answers = [e["worker_id"] for e in ev if e["event"] == "answer"]
lost = [e for e in ev if e["event"] == "eval_lost"]
done = [e for e in ev if e["event"] == "evaluation" and e.get("label") != "final"]
real_joins = [e["session"] for e in ev if e["event"] == "worker" and e.get("change") == "joined" and e["worker_id"] == "real"]
forged = [e for e in ev if e["event"] == "evaluation" and e.get("max") is not None and e["max"] >= 0]
stop = [e["reason"] for e in ev if e["event"] == "stop"]
print("workers joined: %d; answers: %d (%s); parts lost: %d; evaluations complete: %d"
      % (len(joined), len(answers), ", ".join(sorted(set(answers))), len(lost), len(done)))
ok = True
if "ghost" not in joined:
    print("FAIL: the invented workers never joined the roster"); ok = False
if not answers or set(answers) != {"real"}:
    print("FAIL: answers not all from the real worker"); ok = False
if lost:
    print("FAIL: %d evaluation parts lost" % len(lost)); ok = False
if len(done) < 3:
    print("FAIL: only %d evaluations completed" % len(done)); ok = False
if not real_joins or real_joins[0] != 1:
    print("FAIL: the pre-emptor did not join as worker real before it (sessions joined: %s)" % real_joins); ok = False
if forged:
    print("FAIL: %d evaluations hold the pre-emptor's return of 0 (first: %s)" % (len(forged), forged[0])); ok = False
if not stop or not stop[0].startswith("time limit"):
    print("FAIL: the run did not end at its time limit: %s" % stop); ok = False
sys.exit(0 if ok else 1)
PY
farm_test_end "$(tail -1 "$dir/intruder.log")"
