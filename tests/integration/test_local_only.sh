#!/usr/bin/env bash
# The one-host quickstart is reachable from this host only: deploy/run-local.sh gives its learner
# and workers deploy/discovery/local.xml (shared memory only), and a learner with that profile,
# training with a worker, has no socket on an address other than loopback.
#   tests/integration/test_local_only.sh LEARNER_BIN WORKER_BIN INTRUDER_BIN SOURCE_DIR
# The control: farm_intruder with the default profile (shared memory + UDP on every interface) must
# show a non-loopback socket, so a checker that finds nothing is not passing for the wrong reason.
set -uo pipefail
learner=$(readlink -f "$1") worker=$(readlink -f "$2") intruder=$(readlink -f "$3") src=$(readlink -f "$4")
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init local-only 91
local_profile="$src/deploy/discovery/local.xml"

# Prints "PROTO ADDRESS:PORT" for every IPv4/IPv6 UDP or TCP socket process $1 holds that is bound
# to an address other than loopback (0.0.0.0 and :: included: they listen on every interface).
outside_sockets() {
  local pid=$1 inodes
  inodes=$(for fd in /proc/"$pid"/fd/*; do readlink "$fd"; done 2>/dev/null | sed -n 's/^socket:\[\([0-9]*\)\]$/\1/p')
  [ -n "$inodes" ] || return 0
  for proto in udp tcp udp6 tcp6; do
    awk -v proto="$proto" -v inodes=" $(echo $inodes) " 'NR > 1 && index(inodes, " " $10 " ") {
      split($2, a, ":"); addr = a[1]
      if (addr == "0100007F" || addr ~ /^7F/ || addr == "00000000000000000000000001000000") next
      print proto, $2 }' /proc/"$pid"/net/"$proto"
  done
}

# 1. The quickstart passes the loopback-only profile to every process it starts.
[ "$(grep -c 'discovery/local.xml' "$src/deploy/run-local.sh")" -ge 1 ] ||
  fail "deploy/run-local.sh does not use deploy/discovery/local.xml"
grep -q -- '--dds-profiles "$PROFILES"' "$src/deploy/run-local.sh" ||
  fail "deploy/run-local.sh does not pass --dds-profiles \"\$PROFILES\" to its processes"

# 2. A learner and a worker with that profile train, and the learner has no socket off loopback.
cat >"$dir/cfg.txtpb" <<'EOF'
experiment_id: "it_local_only"
seed: 3
task { name: "pendulum" }
sac { hidden: 32 hidden: 32 learning_starts: 200 publish_every_updates: 25 }
worker { envs_per_worker: 4 steps_per_batch: 25 max_batches_per_version: 4 }
eval { episodes: 2 every_seconds: 5 final_episodes: 2 }
stop { max_seconds: 20 }
log_every_seconds: 2
EOF
"$learner" --config "$dir/cfg.txtpb" --run-dir "$dir/run" --domain "$domain" --dds-profiles "$local_profile" \
  >"$dir/learner.log" 2>&1 &
lpid=$!; pids+=($lpid)
"$worker" --domain "$domain" --id local-1 --dds-profiles "$local_profile" >"$dir/worker.log" 2>&1 &
pids+=($!)
# Sockets are looked at once the worker's batches arrive, so every transport is open by then.
if wait_text "$dir/run/events.jsonl" '"worker_id":"local-1"' 60; then
  sleep 2
  bad=$(outside_sockets "$lpid")
  [ -z "$bad" ] || fail "the learner with $local_profile has sockets off loopback: $(echo $bad)"
  echo "learner (pid $lpid) sockets off loopback: ${bad:-none}"
else
  fail "the learner never heard of the worker over shared memory: $(tail -5 "$dir/learner.log")"
fi
wait "$lpid"; rc=$?
[ $rc = 0 ] || fail "learner exited $rc: $(tail -5 "$dir/learner.log")"
[ "$(summary_of "$dir/run" 's["batches_ok"] > 0')" = true ] ||
  fail "no batch arrived over shared memory: $(events "$dir/run" summary)"

# 3. The control: the default profile listens on every interface, and the checker sees it.
"$intruder" --domain "$domain" --id control --seconds 4 --events "$dir/control.jsonl" >"$dir/control.log" 2>&1 &
cpid=$!; pids+=($cpid)
wait_has_event "$dir/control.jsonl" joined 10 || fail "control never joined: $(cat "$dir/control.log")"
sleep 1
control=$(outside_sockets "$cpid")
[ -n "$control" ] || fail "the checker found no socket off loopback for the default profile: it sees nothing"
echo "control with the default profile, sockets off loopback: $(echo $control)"
wait "$cpid"
farm_test_end "quickstart learner bound to this host only"
