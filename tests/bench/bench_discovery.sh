#!/usr/bin/env bash
# DDS discovery at scale on one machine: N cheap idle participants (discovery_participant: a real
# Fast DDS participant with the farm's status profiles, one writer and one reader) spread over M
# network namespaces joined by veth pairs to a bridge, and the time until every one has matched the
# endpoints it expects, with simple discovery (multicast SPDP over the bridge) and with the
# Discovery Server pair (fastdds discovery, primary and backup, in the bridge's namespace). Also
# the discovery traffic: bytes and packets the participants' namespaces sent onto the bridge and
# were delivered from it (the hub-side veth counters, /sys/class/net/*/statistics), and over their
# own loopback (participants of one namespace), read when the last participant matched.
#
#   tests/bench/bench_discovery.sh PARTICIPANT_BIN SOURCE_DIR [--counts 10,50,100,200]
#       [--namespaces 10] [--modes simple,server] [--layouts mesh,star] [--timeout 180]
#
# mesh: every participant writes and reads farm/WorkerStatus, so it must match all N-1 others;
# star: the farm's layout, one learner-like participant (reads WorkerStatus, writes LearnerStats)
# that must match N-1 workers, and N-1 workers that must each match it (1).
# Profiles: deploy/discovery/client_udp.xml (UDPv4 only: namespaces share /dev/shm, so shared
# memory would bypass the network under test); with ROS_DISCOVERY_SERVER for the server mode.
# Needs root (ip netns) and fastdds (fastdds-tools) for the server mode. Everything it starts is
# stopped by its process id and every namespace is removed on exit, failure included.
set -uo pipefail
if [ $# -lt 2 ]; then
  echo "usage: $0 PARTICIPANT_BIN SOURCE_DIR [--counts 10,50,100,200] [--namespaces M] [--modes simple,server] [--layouts mesh,star] [--timeout S]" >&2
  exit 2
fi
bin=$(readlink -f "$1") src=$(readlink -f "$2")
shift 2
counts=10,50,100,200 nns=10 modes=simple,server layouts=mesh,star timeout=180
while [ $# -gt 0 ]; do
  case "$1" in
    --counts) counts=${2:?--counts needs a value}; shift 2 ;;
    --namespaces) nns=${2:?--namespaces needs a value}; shift 2 ;;
    --modes) modes=${2:?--modes needs a value}; shift 2 ;;
    --layouts) layouts=${2:?--layouts needs a value}; shift 2 ;;
    --timeout) timeout=${2:?--timeout needs a value}; shift 2 ;;
    *) echo "bench_discovery: unknown option '$1'" >&2; exit 2 ;;
  esac
done
[[ $counts =~ ^[0-9]+(,[0-9]+)*$ ]] || { echo "bench_discovery: --counts: expected numbers like 10,50, got '$counts'" >&2; exit 2; }
for n in ${counts//,/ }; do
  [ "$n" -ge 2 ] && [ "$n" -le 2000 ] || { echo "bench_discovery: --counts: each N must be 2..2000, got $n" >&2; exit 2; }
done
[[ $nns =~ ^[0-9]+$ ]] && [ "$nns" -ge 1 ] && [ "$nns" -le 200 ] ||
  { echo "bench_discovery: --namespaces: expected 1..200, got '$nns'" >&2; exit 2; }
[[ $timeout =~ ^[0-9]+$ ]] && [ "$timeout" -ge 5 ] ||
  { echo "bench_discovery: --timeout: expected whole seconds >= 5, got '$timeout'" >&2; exit 2; }
for m in ${modes//,/ }; do
  [ "$m" = simple ] || [ "$m" = server ] || { echo "bench_discovery: --modes: simple or server, got '$m'" >&2; exit 2; }
done
for l in ${layouts//,/ }; do
  [ "$l" = mesh ] || [ "$l" = star ] || { echo "bench_discovery: --layouts: mesh or star, got '$l'" >&2; exit 2; }
done
[ -x "$bin" ] || { echo "bench_discovery: $bin is not an executable" >&2; exit 2; }
profiles=$src/deploy/discovery/client_udp.xml
[ -f "$profiles" ] || { echo "bench_discovery: no $profiles" >&2; exit 2; }
if [ "$(id -u)" != 0 ]; then echo "bench_discovery: network namespaces need root" >&2; exit 77; fi
if [[ ,$modes, == *,server,* ]] && ! command -v fastdds >/dev/null; then
  echo "bench_discovery: the server mode needs the 'fastdds' tool (Debian package fastdds-tools)" >&2; exit 77
fi

tag=$$
status=0
HUB=fdh_$tag BR=fdbr$tag
dir=$(mktemp -d /tmp/bench-discovery-XXXXXX)
pids=() groups=() made=()
stop_run() {  # the participants and servers of one run, by process id
  for p in "${pids[@]}"; do kill -TERM "$p" 2>/dev/null; done
  for g in "${groups[@]}"; do
    kill -9 $(pgrep -P "$g") 2>/dev/null  # the server itself first, so its wrapper reaps it
    kill -9 -- "-$g" 2>/dev/null
  done
  for _ in $(seq 50); do
    alive=0
    for p in "${pids[@]}"; do kill -0 "$p" 2>/dev/null && alive=1 && break; done
    [ $alive = 0 ] && break
    sleep 0.1
  done
  for p in "${pids[@]}"; do kill -9 "$p" 2>/dev/null; done
  wait 2>/dev/null
  pids=() groups=()
}
cleanup() {
  stop_run
  for ns in "${made[@]}"; do ip netns del "$ns" 2>/dev/null; done
  # Kept when a participant did not match (its last line says how far it got) or on request.
  if [ "$status" = 0 ] && [ -z "${FARM_KEEP_LOGS:-}" ]; then rm -rf "$dir"; else echo "logs kept in $dir" >&2; fi
}
trap cleanup EXIT
trap 'exit 130' INT TERM

# The hub: a bridge at 10.79.0.1 (the Discovery Servers' address); namespace i at 10.79.1.(i+1).
set -e
ip netns add $HUB; made+=($HUB)
ip -n $HUB link add $BR type bridge
ip -n $HUB link set dev $BR type bridge mcast_snooping 0
ip -n $HUB addr add 10.79.0.1/16 dev $BR
ip -n $HUB link set lo up
ip -n $HUB link set $BR up
ip -n $HUB route add 224.0.0.0/4 dev $BR
for i in $(seq 0 $((nns - 1))); do
  ns=fdn${i}_$tag h=fvh${i}_$tag e=fve${i}_$tag
  ip netns add $ns; made+=($ns)
  ip link add $h type veth peer name $e
  ip link set $h netns $HUB
  ip link set $e netns $ns
  ip -n $HUB link set $h master $BR
  ip -n $HUB link set $h up
  ip -n $ns addr add 10.79.1.$((i + 1))/16 dev $e
  ip -n $ns link set lo up
  ip -n $ns link set $e up
  ip -n $ns route add 224.0.0.0/4 dev $e  # SPDP multicast over the bridge
done
set +e

# Sums over the hub-side veths (rx: what the namespaces sent; tx: what the bridge delivered to
# them) and over the namespaces' loopback: "rx_bytes rx_packets tx_bytes tx_packets lo_bytes lo_packets".
counters() {
  ip netns exec $HUB sh -c '
    rb=0 rp=0 tb=0 tp=0
    for d in /sys/class/net/fvh*; do
      s=$d/statistics
      rb=$((rb + $(cat $s/rx_bytes))) rp=$((rp + $(cat $s/rx_packets)))
      tb=$((tb + $(cat $s/tx_bytes))) tp=$((tp + $(cat $s/tx_packets)))
    done
    echo $rb $rp $tb $tp'
  local lb=0 lp=0
  for i in $(seq 0 $((nns - 1))); do
    read -r b p < <(ip netns exec fdn${i}_$tag sh -c 'echo $(cat /sys/class/net/lo/statistics/tx_bytes) $(cat /sys/class/net/lo/statistics/tx_packets)')
    lb=$((lb + b)) lp=$((lp + p))
  done
  echo $lb $lp
}

# UDP port PORT bound in namespace NS (a Discovery Server's participant listens there).
udp_bound() {  # NS PORT
  [ -n "$(ip netns exec "$1" ss -Hlun "sport = :$2")" ]
}
# From the participants' events (RUN/p*.jsonl): "GOT LAUNCH ALL AFTER MEDIAN": how many matched,
# the time to start them all (T0 to TL), the last match from T0 and from TL (-1.00 when none
# matched), and the median of each one's own time from its start to its match (-1 when none).
match_times() {  # RUN T0 TL
  python3 - "$@" <<'PY'
import glob, json, sys
run, t0, tl = sys.argv[1], float(sys.argv[2]), float(sys.argv[3])
started, matched = {}, {}
for path in glob.glob(run + "/p*.jsonl"):
    for line in open(path, errors="replace"):
        try:
            e = json.loads(line)
        except ValueError:
            continue  # a line cut short by a killed participant
        if e.get("event") == "started":
            started[e["name"]] = e["unix_s"]
        elif e.get("event") == "matched":
            matched[e["name"]] = e["unix_s"]
k = len(matched)
last = max(matched.values(), default=0)
own = sorted(float("%.3f" % (t - started.get(p, 0))) for p, t in matched.items())
med = "%.2f" % own[(k + 1) // 2 - 1] if k else "-1"
print("%d %.2f %.2f %.2f %s" % (k, tl - t0, last - t0 if k else -1, last - tl if k else -1, med))
PY
}

echo "bench_discovery: nproc $(nproc), 1-minute load average $(cut -d' ' -f1 /proc/loadavg) at start"
echo "bench_discovery: $nns namespaces on one bridge, participants spread round-robin; profiles $profiles"
printf '%-7s %-5s %5s %9s %11s %11s %11s %12s %10s %12s %10s %11s %6s\n' mode layout N launch_s all_matched_s \
  after_launch p50_own_s sent_bytes sent_pkts delivered_b lo_bytes per_part_B unmatched
domain=40
for mode in ${modes//,/ }; do
  for layout in ${layouts//,/ }; do
    for n in ${counts//,/ }; do
      domain=$((domain + 1))
      run=$dir/$mode-$layout-$n
      mkdir -p "$run"
      unset ROS_DISCOVERY_SERVER
      if [ $mode = server ]; then
        # Fresh servers for each run: clients of one server meet whatever their domain. They run
        # without ROS_DISCOVERY_SERVER (tests/integration/test_multihost_netns.sh says why).
        setsid ip netns exec $HUB fastdds discovery -i 0 -l 10.79.0.1 -p 11811 >"$run/ds0.log" 2>&1 &
        groups+=($!)
        setsid ip netns exec $HUB fastdds discovery -i 1 -l 10.79.0.1 -p 11812 >"$run/ds1.log" 2>&1 &
        groups+=($!)
        # Each up when its UDP port is bound (its participant exists), within 10 s.
        for i in 0 1; do
          for _ in $(seq 100); do udp_bound $HUB $((11811 + i)) && break; sleep 0.1; done
          udp_bound $HUB $((11811 + i)) || { echo "discovery server $i did not start: $(cat "$run/ds$i.log")"; status=1; }
        done
        export ROS_DISCOVERY_SERVER="10.79.0.1:11811;10.79.0.1:11812"
      fi
      read -r rb0 rp0 tb0 tp0 lb0 lp0 < <(counters | tr '\n' ' ')
      t_start=$(date +%s.%N)
      for p in $(seq 0 $((n - 1))); do
        role=mesh expect=$((n - 1))
        if [ $layout = star ]; then
          if [ $p = 0 ]; then role=learner; else role=worker expect=1; fi
        fi
        ip netns exec fdn$((p % nns))_$tag "$bin" --name p$p --role $role --expect $expect \
          --max-seconds $((timeout + 60)) --domain $domain --dds-profiles "$profiles" --events "$run/p$p.jsonl" \
          >"$run/p$p.log" 2>&1 &
        pids+=($!)
      done
      t_launched=$(date +%s.%N)
      deadline=$(($(date +%s) + timeout))
      while :; do
        done_n=$(grep -lF '"event":"matched"' "$run"/p*.jsonl 2>/dev/null | wc -l)
        [ "$done_n" -ge "$n" ] && break
        [ "$(date +%s)" -ge "$deadline" ] && break
        sleep 0.2
      done
      read -r rb1 rp1 tb1 tp1 lb1 lp1 < <(counters | tr '\n' ' ')
      stop_run
      unset ROS_DISCOVERY_SERVER
      read -r got launch all after med < <(match_times "$run" "$t_start" "$t_launched")
      sent=$((rb1 - rb0)) sentp=$((rp1 - rp0)) deliv=$((tb1 - tb0)) lo=$((lb1 - lb0))
      printf '%-7s %-5s %5d %9s %11s %11s %11s %12d %10d %12d %10d %11d %6d\n' $mode $layout $n $launch $all $after $med \
        $sent $sentp $deliv $lo $(((sent + lo) / n)) $((n - got))
      [ "$got" -lt "$n" ] && status=1
    done
  done
done
echo "bench_discovery: columns: launch_s the time to start all N; all_matched_s from the first start to the last"
echo "  participant's match; after_launch the same from the last start; p50_own_s the median time from a"
echo "  participant's own start to its match; sent_bytes/sent_pkts what the namespaces sent onto the bridge,"
echo "  delivered_b what the bridge delivered to them (multicast is copied to every port), lo_bytes the"
echo "  loopback traffic inside the namespaces, per_part_B (sent + lo) / N; unmatched: participants that did"
echo "  not match within ${timeout} s. Load average at end: $(cut -d' ' -f1 /proc/loadavg)"
exit $status
