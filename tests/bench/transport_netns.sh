#!/usr/bin/env bash
# TransitionBatch transport between two network namespaces joined by a veth pair, against a
# plain TCP stream over the same link (as root):
#   [SOCKET_BUFFER_MAX=BYTES] tests/bench/transport_netns.sh BENCH_TRANSPORT_BIN PROFILES_XML \
#       [bench_transport flags...]
# PROFILES_XML should leave shared memory out (deploy/discovery/client_udp.xml): processes in
# two namespaces of one host could still meet through /dev/shm, which hosts cannot.
set -euo pipefail
bench=$(readlink -f "$1")
profiles=$(readlink -f "$2")
shift 2
cleanup() {
  ip netns del farm_bench_a 2>/dev/null || true
  ip netns del farm_bench_b 2>/dev/null || true
}
trap cleanup EXIT
cleanup
ip netns add farm_bench_a
ip netns add farm_bench_b
ip link add farm_va type veth peer name farm_vb
ip link set farm_va netns farm_bench_a
ip link set farm_vb netns farm_bench_b
ip -n farm_bench_a addr add 10.77.0.1/24 dev farm_va
ip -n farm_bench_b addr add 10.77.0.2/24 dev farm_vb
for ns in farm_bench_a farm_bench_b; do
  ip -n $ns link set lo up
  # SOCKET_BUFFER_MAX=BYTES raises the kernel's cap on socket buffers (net.core.rmem_max and
  # wmem_max) in both namespaces, so the profile's sendBufferSize/receiveBufferSize take effect.
  if [ -n "${SOCKET_BUFFER_MAX:-}" ]; then
    ip netns exec $ns sysctl -qw net.core.rmem_max="$SOCKET_BUFFER_MAX" net.core.wmem_max="$SOCKET_BUFFER_MAX"
  fi
done
ip -n farm_bench_a link set farm_va up
ip -n farm_bench_b link set farm_vb up
# DDS discovery is multicast: route it over the link.
ip -n farm_bench_a route add 224.0.0.0/4 dev farm_va
ip -n farm_bench_b route add 224.0.0.0/4 dev farm_vb
ip netns exec farm_bench_a "$bench" --dds-profiles "$profiles" \
  --writer-prefix "ip netns exec farm_bench_b" --tcp-limit 10.77.0.1 "$@"
