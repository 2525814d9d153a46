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
joined=$(grep -c "worker hb-[0-9]* on .* joined" "$dir/learner.log")
[ "$joined" = "$n" ] || fail "$joined of $n workers joined"
# The evaluations answered with every worker present, and how long each took on its worker.
python3 - "$dir/learner.log" "$n" <<'PY' || failed=1
import re, sys
lines = open(sys.argv[1]).read().splitlines()
n = int(sys.argv[2])
joined, long_evals = 0, []
for line in lines:
    if re.search(r"worker hb-\d+ on .* joined", line):
        joined += 1
    m = re.search(r"evaluation \d+ answered by (hb-\d+) \(([0-9.]+) s on the worker", line)
    if m and joined == n:
        long_evals.append((m.group(1), float(m.group(2))))
print("evaluations with all %d workers present: %s" % (n, ", ".join("%s %.1f s" % e for e in long_evals)))
if not any(s >= 4 for _, s in long_evals):
    print("FAIL: no evaluation kept a worker busy for 2 heartbeat timeouts (4 s); the test proves nothing")
    sys.exit(1)
PY
# From the moment every worker is present: before it, 40 workers starting at once on 2 cores can
# starve one of them past the timeout (its own silence, not the learner's), which is not what this
# test is about.
all_in=$(grep -n "worker hb-[0-9]* on .* joined" "$dir/learner.log" | sed -n "${n}p" | cut -d: -f1)
starting=$(head -n "${all_in:-0}" "$dir/learner.log" | grep -c "marked dead")
[ "$starting" = 0 ] || echo "note: $starting marked dead while the $n workers were still starting"
tail -n +"${all_in:-1}" "$dir/learner.log" | grep "marked dead" | head -3 | sed 's/^/FAIL: /'
tail -n +"${all_in:-1}" "$dir/learner.log" | grep -q "marked dead" && failed=1
farm_test_end "$n workers, none marked dead"
