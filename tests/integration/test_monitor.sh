#!/usr/bin/env bash
# farm-monitor against a real farm on this host (learner + 2 workers over Fast DDS):
#   tests/integration/test_monitor.sh LEARNER_BIN WORKER_BIN MONITOR_BIN SOURCE_DIR
# 1. `farm-monitor --once` lists both workers with non-zero steps/s and the learner's statistics.
# 2. `farm-monitor --log FILE` runs while one worker is killed with SIGKILL and another started:
#    the JSON lines show the killed one alive, then dead (out of the totals), and the new one.
# 3. Flag errors are clear, and an empty domain gives exit 1 with a message.
# 4. The discovery profiles in deploy/discovery/ carry the same topic QoS as deploy/fastdds_profiles.xml.
set -uo pipefail
learner=$(readlink -f "$1") worker=$(readlink -f "$2") monitor=$(readlink -f "$3") src=$(readlink -f "$4")
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init monitor 77

# 4. Topic QoS of the discovery profiles = the farm's (everything from the first topic profile on).
topic_qos() { sed -n '/<!-- ExperimentSpec and PolicyWeights/,$p' "$1"; }
for f in "$src"/deploy/discovery/*.xml; do
  diff <(topic_qos "$src/deploy/fastdds_profiles.xml") <(topic_qos "$f") >/dev/null ||
    fail "$f: topic profiles differ from deploy/fastdds_profiles.xml"
done

# 3. Errors.
out=$("$monitor" --interval 0 2>&1); rc=$?
[ $rc = 2 ] && grep -q -- "--interval: Value 0 is not a number in \[0.1, 3600\]" <<<"$out" || fail "bad --interval: rc $rc, '$out'"
out=$("$monitor" --frobnicate 2>&1); rc=$?
[ $rc = 2 ] && grep -q "not expected: --frobnicate" <<<"$out" || fail "unknown flag: rc $rc, '$out'"
out=$("$monitor" --once --wait 1 --domain $(( (domain + 100) % 200 + 20 )) 2>&1); rc=$?
[ $rc = 1 ] && grep -q "nothing found on DDS domain" <<<"$out" || fail "empty domain: rc $rc, '$out'"

cat >"$dir/cfg.txtpb" <<'EOF'
experiment_id: "it_monitor"
seed: 5
task { name: "pendulum" }
sac { hidden: 64 hidden: 64 actor_lr: 1e-3 critic_lr: 1e-3 alpha_lr: 1e-3 learning_starts: 1000 publish_every_updates: 25 }
worker { envs_per_worker: 8 steps_per_batch: 25 max_batches_per_version: 20 }
eval { episodes: 5 every_seconds: 10 final_episodes: 5 }
checkpoint_every_seconds: 30
log_every_seconds: 1
stop { max_seconds: 45 }
EOF
"$learner" --config "$dir/cfg.txtpb" --run-dir "$dir/run" --domain $domain >"$dir/learner.log" 2>&1 & pids+=($!)
"$worker" --domain $domain --id mon-a --events "$dir/worker-a.jsonl" >"$dir/worker-a.log" 2>&1 & pids+=($!)
"$worker" --domain $domain --id mon-b --events "$dir/worker-b.jsonl" >"$dir/worker-b.log" 2>&1 & pid_b=$!; pids+=($pid_b)

for w in a b; do
  wait_worker_event "$dir/worker-$w.jsonl" joined 30 || fail "worker mon-$w did not join: $(tail -5 "$dir/worker-$w.log")"
done
sleep 4

# 1. One snapshot: both workers, non-zero steps/s, the learner's block.
"$monitor" --domain $domain --once >"$dir/once.txt" 2>&1; rc=$?
echo "--- farm-monitor --once:"; cat "$dir/once.txt"
[ $rc = 0 ] || fail "farm-monitor --once exited $rc"
for w in mon-a mon-b; do
  rate=$(awk -v w=$w '$2 == w { print $4 }' "$dir/once.txt")
  [ -n "$rate" ] && awk -v r="$rate" 'BEGIN { exit !(r > 0) }' || fail "$w not listed with non-zero steps/s (got '$rate')"
done
grep -q "^TOTAL .*2 live" "$dir/once.txt" || fail "totals do not count 2 live workers"
grep -q "ingest .*steps/s" "$dir/once.txt" || fail "no learner statistics in the snapshot"

# 2. The log while mon-b dies and mon-c joins.
"$monitor" --domain $domain --log "$dir/monitor.jsonl" --timeout 3 >"$dir/monitor.out" 2>&1 & mon=$!; pids+=($mon)
sleep 4
{ kill -9 $pid_b; wait $pid_b; } 2>/dev/null
sleep 7
"$worker" --domain $domain --id mon-c --events "$dir/worker-c.jsonl" >"$dir/worker-c.log" 2>&1 & pids+=($!)
wait_worker_event "$dir/worker-c.jsonl" joined 30 || fail "worker mon-c did not join"
sleep 5
kill -INT $mon; wait $mon; rc=$?
[ $rc = 0 ] || fail "farm-monitor (live) exited $rc on SIGINT"
grep -q $'\033\[H\033\[2J' "$dir/monitor.out" && fail "ANSI clear written to a file (not a terminal)"

python3 - "$dir/monitor.jsonl" <<'EOF' || failed=1
import json, sys
lines = [json.loads(l) for l in open(sys.argv[1])]
print(f"--- {len(lines)} JSON lines; states of mon-b and mon-c over time:")
def state(rec, wid):
    for w in rec["workers"]:
        if w["id"] == wid:
            return w["state"]
    return None
b = [state(r, "mon-b") for r in lines]
c = [state(r, "mon-c") for r in lines]
print("mon-b:", " ".join(s or "-" for s in b))
print("mon-c:", " ".join(s or "-" for s in c))
ok = True
def check(cond, msg):
    global ok
    if not cond:
        print("FAIL:", msg); ok = False
for key in ("time", "workers", "learner", "totals"):
    check(all(key in r for r in lines), f"a line lacks '{key}'")
check(len(lines) >= 12, f"only {len(lines)} lines for ~16 s at 1 line/s")
alive_b = [i for i, s in enumerate(b) if s not in (None, "dead")]
dead_b = [i for i, s in enumerate(b) if s == "dead"]
check(len(alive_b) >= 2, "mon-b not listed alive before it was killed")
check(dead_b and alive_b and dead_b[0] > alive_b[-1], "mon-b never shown dead after it was killed")
check(all(s in ("dead", None) for s in b[dead_b[0]:]) if dead_b else False, "mon-b came back to life")
check(c[0] is None, "mon-c listed before it was started")
check(c[-1] not in (None, "dead"), "mon-c not listed alive at the end")
last = lines[-1]
check(last["totals"]["live"] == 2 and last["totals"]["dead"] >= 1,
      f"final totals {last['totals']} (expected 2 live: mon-a, mon-c; mon-b dead)")
live_ids = sorted(w["id"] for w in last["workers"] if w["alive"])
check(live_ids == ["mon-a", "mon-c"], f"live workers at the end: {live_ids}")
check(last["learner"] is not None and last["learner"]["experiment"] == "it_monitor", "no learner object")
# The dead worker is out of the totals: total steps/s = the live ones' sum.
s = sum(w["steps_per_s"] or 0 for w in last["workers"] if w["alive"] and w["state"] != "finished")
check(abs(s - (last["totals"]["steps_per_s"] or 0)) < 1e-3 * max(1, s), "totals include a dead worker")
sys.exit(0 if ok else 1)
EOF

if [ "$failed" = 0 ]; then echo "PASS"; exit 0; fi
echo "--- learner log tail:"; tail -5 "$dir/learner.log"
exit 1
