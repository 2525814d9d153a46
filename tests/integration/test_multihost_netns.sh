#!/usr/bin/env bash
# Three "hosts" on this machine: network namespaces joined by veth pairs to a bridge in the first.
#   A 10.77.0.1: Discovery Servers (primary id 0 on port 11811, backup id 1 on 11812), farm-learner
#   B 10.77.0.2: farm-worker host-b        C 10.77.0.3: farm-worker host-c
# No multicast route anywhere (simple discovery cannot work) and no shared memory (namespaces
# share /dev/shm, so the profile is UDPv4 only). Two farms run at once, on two domains:
# - the trusted-network farm meets through the Discovery Server pair: a short SAC pendulum run
#   must take batches from both workers with nothing lost, bring new weights to both, and
#   `farm-monitor --once` in A must list both with non-zero steps/s, also after the primary
#   discovery server is killed (the backup carries on);
# - the secured farm, the documented multi-host default: every process with a certificate from
#   deploy/make-pki.sh, discovery by unicast to A (deploy/discovery/peers_udp.xml; Fast DDS
#   2.9.1's Discovery Server cannot carry DDS Security, see that file). The same checks, and a
#   participant without a certificate in C that sends batches and reads for the spec and the
#   weights must match no learner, receive nothing, and get no batch accepted.
#   tests/integration/test_multihost_netns.sh LEARNER_BIN WORKER_BIN MONITOR_BIN SOURCE_DIR INTRUDER_BIN
# Needs root (ip netns); exits 77 (skipped) without it. Commands: docs/guides/hosts-and-security.md.
set -uo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"  # the readers of the records: events, summary_of, worker_events
learner=$(readlink -f "$1") worker=$(readlink -f "$2") monitor=$(readlink -f "$3") src=$(readlink -f "$4")
intruder=$(readlink -f "$5")
SKIP=77
A=farm_a_$$ B=farm_b_$$ C=farm_c_$$
BR=fbr$$ HB=fhb$$ HC=fhc$$ EB=feb$$ EC=fec$$
dir=$(mktemp -d /tmp/farm-netns-test-XXXXXX)
domain=$((20 + $$ % 200)) sdomain=$((21 + $$ % 200))
export ROS_DISCOVERY_SERVER="10.77.0.1:11811;10.77.0.1:11812"
unset FASTRTPS_DEFAULT_PROFILES_FILE FASTDDS_ENVIRONMENT_FILE FARM_SECURITY_DIR
client_profiles=$src/deploy/discovery/client_udp.xml
monitor_profiles=$src/deploy/discovery/super_client_udp.xml
peers_profiles=$src/deploy/discovery/peers_udp.xml  # the secured farm's: unicast to 10.77.0.1
pki=$dir/pki
pids=()
groups=()
failed=0
made_ns=0
fail() { echo "FAIL: $*"; failed=1; }
cleanup() {
  for p in "${pids[@]}"; do kill -9 "$p" 2>/dev/null; done
  for g in "${groups[@]}"; do
    kill -9 $(pgrep -P "$g") 2>/dev/null  # the server first, so its wrapper reaps it
    kill -9 -- "-$g" 2>/dev/null
  done
  wait 2>/dev/null
  if [ $made_ns = 1 ]; then
    for ns in $A $B $C; do ip netns del $ns 2>/dev/null; done
  fi
  if [ "$failed" = 0 ] && [ -z "${FARM_KEEP_LOGS:-}" ]; then rm -rf "$dir"; else echo "logs kept in $dir"; fi
}
trap cleanup EXIT
trap 'exit 130' INT TERM

if [ "$(id -u)" != 0 ]; then
  echo "SKIP: network namespaces need root (running as uid $(id -u))"; exit $SKIP
fi
if ! command -v ip >/dev/null; then
  echo "SKIP: the 'ip' tool (Debian package iproute2) is not installed"; exit $SKIP
fi
if ! ip netns add $A 2>"$dir/netns.err"; then
  echo "SKIP: cannot create a network namespace: $(cat "$dir/netns.err")"; exit $SKIP
fi
made_ns=1
command -v fastdds >/dev/null || { echo "SKIP: the 'fastdds' tool (Debian package fastdds-tools) is not installed"; exit $SKIP; }
set -e
ip netns add $B
ip netns add $C
ip -n $A link add $BR type bridge
ip link add $HB type veth peer name $EB
ip link add $HC type veth peer name $EC
ip link set $HB netns $A
ip link set $HC netns $A
ip link set $EB netns $B
ip link set $EC netns $C
ip -n $A link set $HB master $BR
ip -n $A link set $HC master $BR
ip -n $A addr add 10.77.0.1/24 dev $BR
ip -n $B addr add 10.77.0.2/24 dev $EB
ip -n $C addr add 10.77.0.3/24 dev $EC
for ns in $A $B $C; do ip -n $ns link set lo up; done
ip -n $A link set $BR up
ip -n $A link set $HB up
ip -n $A link set $HC up
ip -n $B link set $EB up
ip -n $C link set $EC up
set +e
for ns in $A $B $C; do
  ip -n $ns route show | grep -q '^224\.\|^default' && fail "namespace $ns has a multicast or default route"
done

# Discovery servers on "host" A.
# `fastdds discovery` (a Python wrapper) runs the server as its child: each gets a process group
# of its own (setsid) so that killing the group stops the server itself. The servers run without
# ROS_DISCOVERY_SERVER: with it set, Fast DDS 2.9.1's server aborts (assertion in
# OutputTrafficManager.hpp) as soon as a client joins after it started.
setsid env -u ROS_DISCOVERY_SERVER ip netns exec $A fastdds discovery -i 0 -l 10.77.0.1 -p 11811 \
  >"$dir/discovery-0.log" 2>&1 & ds0=$!; groups+=($ds0)
setsid env -u ROS_DISCOVERY_SERVER ip netns exec $A fastdds discovery -i 1 -l 10.77.0.1 -p 11812 \
  >"$dir/discovery-1.log" 2>&1 & groups+=($!)
# Each up when its UDP port in A is bound (its participant exists). Up to 10 s each: on a loaded
# 2-core machine the tool has taken more than 1 s.
udp_bound() {  # NAMESPACE PORT
  [ -n "$(ip netns exec "$1" ss -Hlun "sport = :$2")" ]
}
for i in 0 1; do
  for _ in $(seq 50); do udp_bound $A $((11811 + i)) && break; sleep 0.2; done
  udp_bound $A $((11811 + i)) || fail "discovery server $i did not start: $(cat "$dir/discovery-$i.log")"
done

bash "$src/deploy/make-pki.sh" "$pki" learner:learner monitor:monitor worker:host-b worker:host-c >"$dir/pki.log" 2>&1 ||
  { fail "deploy/make-pki.sh failed: $(cat "$dir/pki.log")"; exit 1; }

cat >"$dir/cfg.txtpb" <<'EOF'
experiment_id: "it_multihost"
seed: 7
task { name: "pendulum" }
sac { hidden: 64 hidden: 64 actor_lr: 1e-3 critic_lr: 1e-3 alpha_lr: 1e-3 learning_starts: 1000 publish_every_updates: 25 }
worker { envs_per_worker: 8 steps_per_batch: 25 max_batches_per_version: 20 }
eval { episodes: 5 every_seconds: 10 final_episodes: 10 }
checkpoint_every_seconds: 30
log_every_seconds: 2
stop { max_seconds: 40 }
EOF
ip netns exec $A "$learner" --config "$dir/cfg.txtpb" --run-dir "$dir/run" --domain $domain \
  --dds-profiles "$client_profiles" >"$dir/learner.log" 2>&1 & learner_pid=$!; pids+=($learner_pid)
ip netns exec $B "$worker" --domain $domain --dds-profiles "$client_profiles" --id host-b --envs 8 --threads 1 \
  --log-every 2 --events "$dir/worker-b.jsonl" >"$dir/worker-b.log" 2>&1 & wb=$!; pids+=($wb)
ip netns exec $C "$worker" --domain $domain --dds-profiles "$client_profiles" --id host-c --envs 8 --threads 1 \
  --log-every 2 --events "$dir/worker-c.jsonl" >"$dir/worker-c.log" 2>&1 & wc=$!; pids+=($wc)

# The secured farm: no Discovery Server (ROS_DISCOVERY_SERVER would make its participants clients).
sed 's/it_multihost/it_multihost_secure/; s/max_seconds: 40/max_seconds: 34/' "$dir/cfg.txtpb" >"$dir/cfg-secure.txtpb"
secure() {  # NAMESPACE PROGRAM ARGS...: a process of the secured farm
  local ns=$1; shift
  env -u ROS_DISCOVERY_SERVER ip netns exec $ns "$@" --domain $sdomain --dds-profiles "$peers_profiles"
}
secure $A "$learner" --config "$dir/cfg-secure.txtpb" --run-dir "$dir/run-secure" --security "$pki/learner" \
  >"$dir/learner-secure.log" 2>&1 & slearner_pid=$!; pids+=($slearner_pid)
secure $B "$worker" --envs 8 --threads 1 --log-every 2 --security "$pki/host-b" --events "$dir/worker-sb.jsonl" \
  >"$dir/worker-sb.log" 2>&1 &
swb=$!; pids+=($swb)
secure $C "$worker" --envs 8 --threads 1 --log-every 2 --security "$pki/host-c" --events "$dir/worker-sc.jsonl" \
  >"$dir/worker-sc.log" 2>&1 &
swc=$!; pids+=($swc)
# No certificate, in C: well-formed batches of the experiment, and reads for its spec and weights.
secure $C "$intruder" --experiment it_multihost_secure --id intruder-c --seconds 16 --events "$dir/intruder.jsonl" \
  >"$dir/intruder.log" 2>&1 &
wi=$!; pids+=($wi)

wait_text() {  # FILE REGEX SECONDS
  for _ in $(seq $(($3 * 5))); do grep -qE "$2" "$1" 2>/dev/null && return 0; sleep 0.2; done; return 1
}
for w in b c; do
  wait_worker_event "$dir/worker-$w.jsonl" progress 40 '"state":"running"' ||
    fail "worker host-$w is not running over the discovery server: $(tail -3 "$dir/worker-$w.log")"
  wait_worker_event "$dir/worker-s$w.jsonl" progress 40 '"state":"running"' ||
    fail "secured worker host-$w is not running: $(tail -3 "$dir/worker-s$w.log")"
done
sleep 2

# The monitor as a SUPER_CLIENT of both servers (addresses from its XML): both workers, non-zero steps/s.
check_snapshot() {  # NAME [secure]
  if [ "${2:-}" = secure ]; then
    # Up to 20 s: it must first authenticate with the learner and each worker (a handshake each),
    # which on a loaded 2-core machine was seen to take more than 8 s.
    secure $A "$monitor" --security "$pki/monitor" --once --wait 20 >"$dir/$1.txt" 2>&1
  else
    ip netns exec $A "$monitor" --dds-profiles "$monitor_profiles" --domain $domain --once --wait 8 \
      >"$dir/$1.txt" 2>&1
  fi
  local rc=$?
  echo "--- farm-monitor --once ($1), exit $rc:"; cat "$dir/$1.txt"
  [ $rc = 0 ] || fail "$1: farm-monitor --once exited $rc"
  for w in host-b host-c; do
    local rate
    rate=$(awk -v w=$w '$2 == w { print $4 }' "$dir/$1.txt")
    [ -n "$rate" ] && awk -v r="$rate" 'BEGIN { exit !(r > 0) }' || fail "$1: $w not listed with non-zero steps/s (got '$rate')"
  done
}
check_snapshot monitor-1
check_snapshot monitor-secure secure

# Without the discovery server (simple discovery, multicast) nothing is found: the test network
# really has no multicast, so what worked above went through the servers.
env -u ROS_DISCOVERY_SERVER ip netns exec $A "$monitor" --dds-profiles "$client_profiles" --domain $domain \
  --once --wait 3 >"$dir/monitor-simple.txt" 2>&1
rc=$?
[ $rc = 1 ] || fail "a monitor with simple discovery found the farm (exit $rc): $(cat "$dir/monitor-simple.txt")"

# The primary server goes away: a monitor started now meets the farm through the backup.
{ kill -9 $(pgrep -P $ds0); wait $ds0; } 2>/dev/null
sleep 1
ps -o stat= -g $ds0 | grep -q "^[^Z]" && fail "the primary discovery server is still running"
check_snapshot monitor-2

wait $learner_pid; rc=$?
# A Fast DDS assertion aborts the server, and its tool (the process group's leader) then exits:
# the server itself must still run, a child of the tool.
if [ -z "$(pgrep -P ${groups[1]})" ]; then
  why="its tool still runs"
  ps -o stat= -p ${groups[1]} | grep -q "^[^Z]" || { wait ${groups[1]}; why="its tool exited $?"; }
  fail "the backup discovery server ended ($why): $(tail -3 "$dir/discovery-1.log")"
fi
ps -o stat= -g ${groups[1]} | grep -q "^[^Z]" || fail "the backup discovery server is not running any more"
[ $rc = 0 ] || fail "farm-learner exited $rc: $(tail -5 "$dir/learner.log")"
for p in $wb $wc; do
  for _ in $(seq 150); do kill -0 $p 2>/dev/null || break; sleep 0.2; done
done

check_run() {  # RUN_DIR WORKER_EVENTS_PREFIX: both workers' batches arrived, nothing lost, new weights reached them
  local v
  echo "--- $1/summary.txt:"; cat "$1/summary.txt" 2>/dev/null
  summary_batches_whole "$1" || fail "$1: batch totals: $(events "$1" summary)"
  [ "$(summary_of "$1" 'all(not f["worker_id"].startswith("intruder") for f in s["streams"])')" = true ] ||
    fail "$1: the learner accounted the intruder: $(summary_of "$1" 's["streams"]')"
  for w in b c; do
    [ "$(summary_of "$1" 'len(w("host-'$w'")) > 0 and all(f["received"] > 0 and f["lost"] + f["duplicate"] + f["invalid"] == 0 for f in w("host-'$w'"))')" = true ] ||
      fail "$1: worker host-$w in summary: $(summary_of "$1" 'w("host-'$w'")')"
    # New weights reached the worker: its progress events name the policy version it runs.
    v=$(event_of "$2$w.jsonl" progress 'e["policy_version"]')
    echo "worker host-$w: last policy version v${v:-none}; $(worker_events "$2$w.jsonl" finished)"
    [ "${v:-0}" -gt 0 ] || fail "$2$w.jsonl: worker host-$w never ran a policy version > 0"
  done
}
check_run "$dir/run" "$dir/worker-"

wait $slearner_pid; rc=$?
[ $rc = 0 ] || fail "secured farm-learner exited $rc: $(tail -5 "$dir/learner-secure.log")"
[ "$(event_of "$dir/run-secure/events.jsonl" start 'e["security_dir"]')" = "$pki/learner" ] ||
  fail "the secured learner ran without DDS Security: $(events "$dir/run-secure" start)"
for p in $swb $swc; do
  for _ in $(seq 150); do kill -0 $p 2>/dev/null || break; sleep 0.2; done
done
check_run "$dir/run-secure" "$dir/worker-s"
# The intruder ran (its participant was created) and got nothing either way.
wait $wi; rc=$?
echo "--- intruder: $(cat "$dir/intruder.log")"
[ $rc = 0 ] && has_event "$dir/intruder.jsonl" joined id='"intruder-c"' domain=$sdomain security='""' ||
  fail "the intruder did not run (exit $rc): $(cat "$dir/intruder.jsonl")"
has_event "$dir/intruder.jsonl" sent batch_readers_matched=0 weights_received=0 specs_received=0 ||
  fail "the intruder got through: $(worker_events "$dir/intruder.jsonl" sent)"

if [ "$failed" = 0 ]; then echo "PASS"; exit 0; fi
echo "--- learner log tails:"; tail -n 5 "$dir/learner.log" "$dir/learner-secure.log"
exit 1
