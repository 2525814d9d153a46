#!/usr/bin/env bash
# A heartbeat flood from a certified participant is held to its share and starves no one.
# A secured farm (deploy/make-pki.sh: a learner, a worker hw and a second worker certificate, w2,
# the leaked one) trains on the pendulum; then a participant with w2's certificate floods heartbeats
# under its own name, 2,000 invented sessions every 0.1 s (farm_intruder --flood-heartbeats
# 2000 --beat-every 0.1), at nice 19: it stands for another host, and on two cores its own work
# must not be what the learner loses. From the learner's record: the roster refused the flood past
# the participant's share (`refusal` events counting at least 500), the real
# worker was never marked dead (no `worker` event of change `dead` for hw; the flood's own sessions
# go dead once it stops), the run ends with nothing lost or invalid, and its updates/s (learner.csv)
# with the flood running are at least 0.9 of those with it paused, over five rounds of 3 s paused
# (SIGSTOP) and 3 s running (alternate_attack in lib.sh: a rate that swings by itself weighs on
# both sides alike).
#   tests/integration/test_heartbeat_flood.sh LEARNER WORKER INTRUDER SOURCE_DIR
set -uo pipefail
learner=$(readlink -f "$1") worker=$(readlink -f "$2") intruder=$(readlink -f "$3") src=$(readlink -f "$4")
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init heartbeat-flood 181

pki="$dir/pki"
bash "$src/deploy/make-pki.sh" "$pki" learner:learner worker:hw worker:w2 >"$dir/pki.log" 2>&1 ||
  { fail "deploy/make-pki.sh failed: $(tail -3 "$dir/pki.log")"; farm_test_end; }
pendulum_config "$src" it_beatflood "max_seconds: 58" "$dir/flood.txtpb"
"$learner" --config "$dir/flood.txtpb" --run-dir "$dir/run" --domain $domain --security "$pki/learner" \
  >"$dir/learner.log" 2>&1 & lp=$!; pids+=($lp)
"$worker" --domain $domain --envs 4 --security "$pki/hw" >"$dir/worker.log" 2>&1 & pids+=($!)
# Training for 3 s first: the rate before the flood is one of steady training, not of its start.
for _ in $(seq 150); do read -r e u < <(csv_elapsed_last "$dir/run" updates); [ "${u:-0}" -gt 0 ] && break; sleep 0.2; done
[ "${u:-0}" -gt 0 ] || { fail "the learner made no update in 30 s: $(tail -3 "$dir/worker.log")"; farm_test_end; }
sleep 3
nice -n 19 "$intruder" --domain $domain --experiment it_beatflood --id w2 --security "$pki/w2" --seconds 50 \
  --flood-heartbeats 2000 --beat-every 0.1 >"$dir/intruder.log" 2>&1 & ip=$!; pids+=($ip)
# Measured once the flood is under way (the roster has taken a heartbeat of it: a `worker` event of
# w2), so that what is measured is the flood and not the participant's authentication.
for _ in $(seq 100); do events "$dir/run" worker | grep -cF '"worker_id":"w2"' >/dev/null && break; sleep 0.2; done
alternate_attack $ip "$dir/run" updates 5 3
before=$quiet_rate during=$attack_rate
kill $ip 2>/dev/null
echo "updates/s with the flood paused $before, running $during"
awk -v b="$before" -v d="$during" 'BEGIN { exit !(b > 0 && d >= 0.9 * b) }' ||
  fail "updates/s fell from $before to $during during the heartbeat flood"

wait $lp || fail "the learner exited with $?: $(tail -5 "$dir/learner.log")"
# From the learner's events: the flood's heartbeats refused past the share (the flood reached it),
# no worker marked dead, the summary's batches.
python3 - "$dir/run/events.jsonl" <<'PY' || failed=1
import json, sys
ev = [json.loads(l) for l in open(sys.argv[1])]
over = sum(e["count"] for e in ev if e["event"] == "refusal" and e.get("reason", "").startswith("past 20 a second"))
dead = [e["worker_id"] for e in ev if e["event"] == "worker" and e.get("change") == "dead" and e["worker_id"] == "hw"]
s = [e for e in ev if e["event"] == "summary"]
print("heartbeats refused past the share: %d; the real worker marked dead: %d times" % (over, len(dead)))
ok = True
if over < 500:
    print("FAIL: %d heartbeats refused past the share: the flood did not reach the learner" % over); ok = False
if dead:
    print("FAIL: the real worker was marked dead %d times" % len(dead)); ok = False
if not s or s[-1]["batches_ok"] < 1 or s[-1]["batches_lost"] + s[-1]["batches_duplicate"] + s[-1]["batches_invalid"]:
    print("FAIL: batches lost or invalid, or none: %s" % (s[-1] if s else "no summary event")); ok = False
sys.exit(0 if ok else 1)
PY
farm_test_end "updates/s $before before the flood, $during during it"
