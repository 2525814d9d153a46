#!/usr/bin/env bash
# No live worker is marked dead while the learner is busy: 40 small workers, and a learner whose
# evaluation (run in its main loop) takes longer than the heartbeat timeout. Heartbeats are taken
# as they arrive, not from a history shared by all workers that the busy loop reads too late.
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
# An evaluation of thousands of episodes in the learner's main loop: several heartbeat timeouts long.
eval { episodes: 15000 every_seconds: 4 final_episodes: 2 }
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
# The evaluations that ran with every worker present, and how long the loop was away for each.
python3 - "$dir/learner.log" "$n" <<'PY' || failed=1
import re, sys
lines = open(sys.argv[1]).read().splitlines()
n = int(sys.argv[2])
joined, last_elapsed, waiting_eval, long_evals = 0, None, False, []
for line in lines:
    if re.search(r"worker hb-\d+ on .* joined", line):
        joined += 1
    m = re.match(r"\[learner\] +([0-9.]+)s \|", line)
    if m:
        t = float(m.group(1))
        if waiting_eval and last_elapsed is not None:
            long_evals.append(t - last_elapsed)
        waiting_eval, last_elapsed = False, t
    elif line.startswith("[learner] eval: ") and joined == n:
        waiting_eval = True
print("evaluations with all %d workers present: %s s between progress lines" % (n, ", ".join("%.1f" % g for g in long_evals)))
if not any(g >= 4 for g in long_evals):
    print("FAIL: no evaluation kept the loop away for 2 heartbeat timeouts (4 s); the test proves nothing")
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
