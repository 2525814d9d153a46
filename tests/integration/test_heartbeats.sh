#!/usr/bin/env bash
# No live worker is marked dead while it or the learner is busy: 40 small workers, and evaluations
# of 16,000 episodes, each longer than two heartbeat timeouts, run by one of them (in its
# evaluation thread, beside its training loop and its heartbeats) while the learner's main loop
# takes every worker's heartbeats as they arrive, not from a history shared by all workers.
#   tests/integration/test_heartbeats.sh LEARNER WORKER [WORKERS]
set -uo pipefail
learner=$(readlink -f "$1") worker=$(readlink -f "$2") n=${3:-40}
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init heartbeats 151

cat >"$dir/cfg.txtpb" <<'CFG'
experiment_id: "it_heartbeats"
task { name: "pendulum" }
sac { hidden: 32 hidden: 32 learning_starts: 500 batch_size: 64 publish_every_updates: 50 }
worker { envs_per_worker: 1 steps_per_batch: 50 max_batches_per_version: 2 }
# Evaluations of 16,000 episodes on one worker, among 40 on 2 cores: several heartbeat timeouts
# long (an evaluation must outlast worker_timeout_seconds several times over for the test to mean
# anything); kept whole on one worker (min_episodes_per_worker: 0), not split over the 40.
eval { episodes: 16000 every_seconds: 4 final_episodes: 2 answer_timeout_seconds: 90 min_episodes_per_worker: 0 }
worker_timeout_seconds: 2
checkpoint_every_seconds: 600
log_every_seconds: 1
stop { max_seconds: 75 }
CFG
"$learner" --config "$dir/cfg.txtpb" --run-dir "$dir/run" --domain $domain >"$dir/learner.log" 2>&1 & lp=$!; pids+=($lp)
for i in $(seq 1 "$n"); do
  "$worker" --domain $domain --id hb-$i --log-every 30 >"$dir/worker-$i.log" 2>&1 & pids+=($!)
done
wait $lp; rc=$?
[ $rc = 0 ] || fail "learner exited $rc: $(tail -5 "$dir/learner.log")"
# From the learner's events, in order: the workers' joins, the evaluations answered once every
# worker was present (and how long each took on its worker), and the workers marked dead from
# then on. Before all are present, 40 workers starting at once on 2 cores can starve one of them
# past the timeout (its own silence, not the learner's), which is not what this test is about.
python3 - "$dir/run/events.jsonl" "$n" <<'PY' || failed=1
import json, sys
n = int(sys.argv[2])
events = []
for line in open(sys.argv[1]):
    try:
        events.append(json.loads(line))
    except ValueError:
        pass
joined, long_evals, dead_starting, dead = set(), [], [], []
for e in events:
    if e.get("event") == "worker" and e.get("change") == "joined":
        joined.add(e["worker_id"])
    elif e.get("event") == "worker" and e.get("change") == "dead":
        (dead if len(joined) == n else dead_starting).append(e["worker_id"])
    elif e.get("event") == "answer" and len(joined) == n:
        long_evals.append((e["worker_id"], e["worker_seconds"]))
print("%d of %d workers joined" % (len(joined), n))
print("evaluations with all %d workers present: %s" % (n, ", ".join("%s %.1f s" % e for e in long_evals)))
if dead_starting:
    print("note: %d marked dead while the %d workers were still starting" % (len(dead_starting), n))
ok = True
if len(joined) != n:
    print("FAIL: %d of %d workers joined" % (len(joined), n))
    ok = False
if not any(s >= 4 for _, s in long_evals):
    print("FAIL: no evaluation kept a worker busy for 2 heartbeat timeouts (4 s); the test proves nothing")
    ok = False
for w in dead[:3]:
    print("FAIL: %s marked dead with all workers present" % w)
sys.exit(0 if ok and not dead else 1)
PY
farm_test_end "$n workers, none marked dead"
