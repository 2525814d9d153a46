#!/usr/bin/env bash
# A robot from a model file and one config, trained by a worker that never saw the file: the
# walkthrough of docs/guides/own-robot.md over two "hosts" (network namespaces joined by a veth
# pair, UDP discovery by unicast to the learner, deploy/discovery/peers_udp.xml).
#   A 10.77.0.1: farm-learner --config my_robot/my_robot.txtpb, run from the user's folder
#   B 10.77.0.2: farm-worker, run from an empty folder
# The model's folder is deleted once the learner has read it, so the worker can only have the model
# from the ExperimentSpec. The run must take the worker's batches with nothing lost and answer its
# evaluations, and the worker must have joined the experiment of the task of terms.
# Limits: the shipped config is edited to stop at max_seconds 20 (or earlier at its own goal), to
# start updates after 1,000 steps and to evaluate every 6 s; each edit must match the shipped text
# (the test fails when one matches nothing, as it would when the config changes). The learner must
# have exited 60 s after it started, its final evaluation included; the test takes about 30 s.
#   tests/integration/test_terms_netns.sh LEARNER_BIN WORKER_BIN SOURCE_DIR
# Needs root (ip netns); exits 77 (skipped) without it.
set -uo pipefail
learner=$(readlink -f "$1") worker=$(readlink -f "$2") src=$(readlink -f "$3")
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init terms-netns 131
SKIP=77
A=farm_ta_$$ B=farm_tb_$$ HA=fta$$ HB=ftb$$
made_ns=0
before_cleanup() {
  if [ $made_ns = 1 ]; then ip netns del $A 2>/dev/null; ip netns del $B 2>/dev/null; fi
}
if [ "$(id -u)" != 0 ]; then echo "SKIP: network namespaces need root (uid $(id -u))"; exit $SKIP; fi
command -v ip >/dev/null || { echo "SKIP: the 'ip' tool (Debian package iproute2) is not installed"; exit $SKIP; }
if ! ip netns add $A 2>"$dir/netns.err"; then echo "SKIP: cannot create a network namespace: $(cat "$dir/netns.err")"; exit $SKIP; fi
made_ns=1
set -e
ip netns add $B
ip link add $HA type veth peer name $HB
ip link set $HA netns $A
ip link set $HB netns $B
ip -n $A addr add 10.77.0.1/24 dev $HA
ip -n $B addr add 10.77.0.2/24 dev $HB
for ns in $A $B; do ip -n $ns link set lo up; done
ip -n $A link set $HA up
ip -n $B link set $HB up
set +e
unset ROS_DISCOVERY_SERVER FASTRTPS_DEFAULT_PROFILES_FILE FASTDDS_ENVIRONMENT_FILE FARM_SECURITY_DIR
profiles=$src/deploy/discovery/peers_udp.xml

# The user's folder: the shipped hexapod's config and model, renamed as a robot of their own.
mkdir -p "$dir/user/my_robot" "$dir/empty"
cp -r "$src/deploy/configs/models/hexapod" "$dir/user/my_robot/model"
config=$(cat "$src/deploy/configs/hexapod_sac.txtpb")
# Replaces the one occurrence of FROM (a whole line's text, exact) by TO; fails when FROM is not there once.
edit() {
  local n; n=$(grep -cxF -- "$1" <<<"$(sed 's/^ *//' <<<"$config")")
  [ "$n" = 1 ] || { fail "test set-up: '$1' is in deploy/configs/hexapod_sac.txtpb $n times, not once"; return; }
  config=$(sed "s|^\\( *\\)$1\$|\\1$2|" <<<"$config")
}
edit 'experiment_id: "hexapod_sac"' 'experiment_id: "my_robot"'
edit 'model: "models/hexapod/hexapod.xml"' 'model: "model/hexapod.xml"'
edit 'max_seconds: 600' 'max_seconds: 20'
edit 'learning_starts: 5000' 'learning_starts: 1000'
edit 'every_seconds: 10' 'every_seconds: 6'
printf '%s\n' "$config" >"$dir/user/my_robot/my_robot.txtpb"
for line in 'experiment_id: "my_robot"' 'model: "model/hexapod.xml"' 'max_seconds: 20' 'learning_starts: 1000' 'every_seconds: 6'; do
  grep -qE "^ *$line\$" "$dir/user/my_robot/my_robot.txtpb" || fail "test set-up: '$line' is not in the edited config"
done
[ $failed = 0 ] || exit 1

(cd "$dir/user" && exec ip netns exec $A "$learner" --config my_robot/my_robot.txtpb --run-dir "$dir/run" \
  --domain $domain --dds-profiles "$profiles") >"$dir/learner.log" 2>&1 & lp=$!; pids+=($lp)
wait_event "$dir/run" start 30 || { fail "the learner did not start: $(tail -5 "$dir/learner.log")"; exit 1; }
rm -rf "$dir/user/my_robot/model"
(cd "$dir/empty" && exec ip netns exec $B "$worker" --domain $domain --dds-profiles "$profiles" --id host-b \
  --envs 8 --threads 1 --log-every 5 --events "$dir/worker.jsonl") >"$dir/worker.log" 2>&1 & wp=$!; pids+=($wp)
for _ in $(seq 300); do kill -0 $lp 2>/dev/null || break; sleep 0.2; done
kill -0 $lp 2>/dev/null && fail "the learner runs past 60 s with max_seconds 20: $(tail -3 "$dir/learner.log")"
wait $lp; rc=$?
[ $rc = 0 ] || fail "farm-learner exited $rc: $(tail -5 "$dir/learner.log")"
for _ in $(seq 100); do kill -0 $wp 2>/dev/null || break; sleep 0.2; done
worker_events "$dir/worker.jsonl" joined | grep -qF '"experiment_id":"my_robot"' || fail "the worker did not join: $(tail -5 "$dir/worker.log")"
[ -z "$(ls -A "$dir/empty")" ] || fail "the worker wrote into its folder: $(ls -A "$dir/empty")"
cat "$dir/run/summary.txt" 2>/dev/null
summary_batches_whole "$dir/run" || fail "batch totals: $(events "$dir/run" summary)"
[ "$(summary_of "$dir/run" 's["evals_asked"] >= 1 and s["evals_answered"] == s["evals_asked"] and s["evals_lost"] + s["evals_invalid"] == 0')" = true ] ||
  fail "evaluations: $(events "$dir/run" summary)"
[ "$(summary_of "$dir/run" 'len(w("host-b")) > 0 and all(f["lost"] + f["duplicate"] + f["invalid"] == 0 for f in w("host-b"))')" = true ] ||
  fail "worker host-b not in the summary, or its stream lost batches: $(events "$dir/run" summary)"
farm_test_end
