#!/usr/bin/env bash
# A process started after another was SIGKILLed never listens on the killed one's shared-memory
# ports. Fast DDS gives a new participant the lowest free participant id, the killed one's, and
# recreates that id's port segments, while a live peer may keep writing into the segments it
# had opened before: a learner resumed after a SIGKILL then never heard a worker that outlived the
# killed learner (its roster said "workers 0" for minutes). The ports a process listens on are the
# shared-memory lock files it holds open (/dev/shm/fastrtps_port<N>_el).
# The killed process's 32 MiB data segment is removed by the next process to start, while a live
# one's stays.
# Then the case itself: a learner killed with SIGKILL, a new one started on the same domain, and the
# worker that outlived the first joins the second.
#   tests/integration/test_restart_ports.sh LEARNER WORKER SOURCE_DIR
set -uo pipefail
learner=$(readlink -f "$1") worker=$(readlink -f "$2") src=$(readlink -f "$3")
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init restart-ports 131

# The shared-memory ports process $1 listens on, one per line.
ports_of() { ls -l "/proc/$1/fd" 2>/dev/null | sed -n 's/.*fastrtps_port\([0-9]*\)_el$/\1/p' | sort -u; }
# The data segment process $1 made (it holds the segment's lock file /dev/shm/fastrtps_<16>_el).
segment_of() { ls -l "/proc/$1/fd" 2>/dev/null | sed -n 's/.*\/dev\/shm\/\(fastrtps_[0-9a-z]\{16\}\)_el$/\1/p' | head -1; }
# Waits up to $2 seconds until the learner of run folder $1 has taken a batch (its ingest events
# count them).
wait_batches_taken() {
  for _ in $(seq $(($2 * 5))); do
    [ "$(event_of "$1/events.jsonl" ingest 'e["batches_ok"] >= 1')" = true ] && return 0
    sleep 0.2
  done
  return 1
}
# Waits until process $1 listens on a port (its participant is up); prints them.
wait_ports() {
  local p
  for _ in $(seq 100); do
    p=$(ports_of "$1")
    [ -n "$p" ] && { echo "$p"; return 0; }
    sleep 0.2
  done
  return 1
}

# 1. Three processes in turn; the first is killed before the third starts.
"$worker" --domain $domain --id a >"$dir/a.log" 2>&1 & pa=$!; pids+=($pa)
ports_a=$(wait_ports $pa) || fail "worker a holds no shared-memory port: $(tail -3 "$dir/a.log")"
"$worker" --domain $domain --id b >"$dir/b.log" 2>&1 & pb=$!; pids+=($pb)
ports_b=$(wait_ports $pb) || fail "worker b holds no shared-memory port: $(tail -3 "$dir/b.log")"
seg_a=$(segment_of $pa) seg_b=$(segment_of $pb)
[ -n "$seg_a" ] && [ -n "$seg_b" ] || fail "test set-up: no data segment held by worker a ('$seg_a') or b ('$seg_b')"
kill -9 $pa; wait $pa 2>/dev/null
for p in $ports_a; do
  [ -e "/dev/shm/fastrtps_port$p" ] || fail "test set-up: the killed worker left no segment for port $p"
done
[ -e "/dev/shm/$seg_a" ] || fail "test set-up: the killed worker left no data segment $seg_a"
# Both data segments made old enough to be judged (a younger one may belong to a process that is
# about to lock it): only the killed worker's goes when the next process starts.
touch -d '-2 min' "/dev/shm/${seg_a}_el" "/dev/shm/${seg_b}_el"
"$worker" --domain $domain --id c --events "$dir/c.jsonl" >"$dir/c.log" 2>&1 & pc=$!; pids+=($pc)
ports_c=$(wait_ports $pc) || fail "worker c holds no shared-memory port: $(tail -3 "$dir/c.log")"
[ ! -e "/dev/shm/$seg_a" ] && [ ! -e "/dev/shm/${seg_a}_el" ] ||
  fail "the killed worker's 32 MiB data segment $seg_a is still in /dev/shm after worker c started"
wait_worker_event "$dir/c.jsonl" start 10 || fail "worker c wrote no start event: $(tail -3 "$dir/c.log")"
[ "$(event_of "$dir/c.jsonl" start 'e["shm_segments_removed"] >= 1')" = true ] ||
  fail "worker c does not count the leftover segments it removed: $(worker_events "$dir/c.jsonl" start)"
[ -e "/dev/shm/$seg_b" ] && [ -e "/dev/shm/${seg_b}_el" ] || fail "worker b's data segment $seg_b, in use, was removed"
echo "ports: killed a: $(echo $ports_a), live b: $(echo $ports_b), new c: $(echo $ports_c)"
reused=$(comm -12 <(echo "$ports_a") <(echo "$ports_c"))
[ -z "$reused" ] || fail "the new process listens on the killed one's ports: $(echo $reused)"
[ "$(event_of "$dir/c.jsonl" start 'isinstance(e["participant_id"], int) and e["participant_id"] >= 0')" = true ] ||
  fail "worker c does not say which participant id it took: $(worker_events "$dir/c.jsonl" start)"
kill -9 $pb $pc 2>/dev/null; wait $pb $pc 2>/dev/null
# A UDP-only profile keeps Fast DDS's choice: peers_udp.xml finds the learner by the well-known ports
# of the first participant ids of its host.
"$worker" --domain $domain --id d --dds-profiles "$src/deploy/discovery/peers_udp.xml" --events "$dir/d.jsonl" \
  >"$dir/d.log" 2>&1 & pd=$!
pids+=($pd)
wait_worker_event "$dir/d.jsonl" start 20 || fail "worker d did not start: $(tail -3 "$dir/d.log")"
[ "$(event_of "$dir/d.jsonl" start 'e["participant_id"]')" = null ] ||
  fail "a UDP-only worker asked for a participant id itself: $(worker_events "$dir/d.jsonl" start)"
kill -9 $pd 2>/dev/null; wait $pd 2>/dev/null

# 2. A learner killed with SIGKILL, another started: the worker that outlived the first joins it.
domain2=$((domain + 1))
sed -e 's/max_seconds: 480/max_seconds: 120/' "$src/deploy/configs/pendulum_sac.txtpb" >"$dir/cfg.txtpb"
"$learner" --config "$dir/cfg.txtpb" --run-dir "$dir/run1" --domain $domain2 >"$dir/learner1.log" 2>&1 & l1=$!
pids+=($l1)
"$worker" --domain $domain2 --id w >"$dir/w.log" 2>&1 & pids+=($!)
wait_batches_taken "$dir/run1" 60 || fail "the first learner got no batch: $(tail -3 "$dir/learner1.log")"
kill -9 $l1; wait $l1 2>/dev/null
"$learner" --config "$dir/cfg.txtpb" --run-dir "$dir/run2" --domain $domain2 >"$dir/learner2.log" 2>&1 & pids+=($!)
wait_has_event "$dir/run2/events.jsonl" worker 40 change='"joined"' worker_id='"w"' ||
  fail "the second learner never heard the worker that outlived the first: $(tail -3 "$dir/learner2.log")"
wait_batches_taken "$dir/run2" 60 ||
  fail "the second learner got no batch from that worker: $(tail -3 "$dir/learner2.log")"

farm_test_end "a restarted process takes ports no killed one left behind and removes its data segment"
