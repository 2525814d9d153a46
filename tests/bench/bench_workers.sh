#!/usr/bin/env bash
# Time to goal against the number of workers: one fresh run of CONFIG (same seed) per worker count,
# the learner and its workers on this host.
#   tests/bench/bench_workers.sh LEARNER_BIN WORKER_BIN CONFIG "2 4 8 15" [OUT_DIR]
# Environment:
#   PARALLEL=P      runs side by side (default 1: one after another)
#   CPUS_PER_RUN=C  the k-th side-by-side run (learner and workers) held to cores k*C .. k*C+C-1
#   GPUS=0,1,..     the k-th side-by-side run gets the k-th GPU (CUDA_VISIBLE_DEVICES)
#   DOMAIN=D        run k uses DDS domain D + k (default 120)
# With PARALLEL=4 CPUS_PER_RUN=16 GPUS=0,1,2,3 one 64-core, 4-GPU host runs four counts as four
# 16-core one-GPU hosts would, apart from what they share (memory bandwidth, caches): say so next
# to its figures. Prints one line per count: the time to goal (when the evaluation that met the
# config's stop.eval_goal was asked, or the wall time at a stop.target_eval_return), the stop
# reason, env steps, updates, updates/s, update-to-data (updates per env step), and batches and
# evaluations lost / invalid from the summary.
set -euo pipefail
if [ $# -lt 4 ]; then
  sed -n '2,14p' "$0" >&2
  exit 2
fi
learner=$1 worker=$2 config=$3 counts=$4
out=${5:-/tmp/farm_bench_workers}
parallel=${PARALLEL:-1} cpus=${CPUS_PER_RUN:-0} domain0=${DOMAIN:-120}
IFS=, read -r -a gpus <<<"${GPUS:-}"
for b in "$learner" "$worker"; do
  [ -x "$b" ] || { echo "bench_workers: $b is not an executable" >&2; exit 2; }
done
[ -r "$config" ] || { echo "bench_workers: cannot read config $config" >&2; exit 2; }
if [ "$cpus" -gt 0 ] && [ $((cpus * parallel)) -gt "$(nproc)" ]; then
  echo "bench_workers: CPUS_PER_RUN $cpus x PARALLEL $parallel is more than this host's $(nproc) cores" >&2
  exit 2
fi
read -r -a list <<<"$counts"
if [ $((domain0 + ${#list[@]} - 1)) -gt 232 ] || [ "$domain0" -lt 0 ]; then
  echo "bench_workers: DOMAIN $domain0 .. $((domain0 + ${#list[@]} - 1)) (one per count) is outside DDS's 0..232" >&2
  exit 2
fi
mkdir -p "$out"
echo "host: $(nproc) cores, load $(cut -d' ' -f1-3 /proc/loadavg); config $config; parallel $parallel," \
  "cores per run ${cpus:-all}, GPUs ${GPUS:-as the config says}"

start_run() {  # COUNT SLOT K; sets last_pid
  local n=$1 slot=$2 k=$3 run="$out/w$1" pin=() i
  rm -rf "$run"
  mkdir -p "$run"
  if [ "$cpus" -gt 0 ]; then pin=(taskset -c "$((slot * cpus))-$((slot * cpus + cpus - 1))"); fi
  (
    if [ ${#gpus[@]} -gt 0 ]; then export CUDA_VISIBLE_DEVICES=${gpus[$((slot % ${#gpus[@]}))]}; fi
    for i in $(seq 1 "$n"); do
      "${pin[@]}" "$worker" --domain $((domain0 + k)) --id "bw$n-$i" >"$run/worker-$i.log" 2>&1 &
    done
    "${pin[@]}" "$learner" --config "$config" --domain $((domain0 + k)) --run-dir "$run/learner" \
      >"$run/learner.log" 2>&1 || echo "learner exit $?" >"$run/failed"
    # Workers end with the learner's run; one that does not (the learner failed before it
    # published anything) is ended after 30 s.
    for _ in $(seq 30); do [ -z "$(jobs -pr)" ] && break; sleep 1; done
    kill $(jobs -pr) 2>/dev/null || true
    wait
  ) </dev/null >/dev/null 2>&1 &
  last_pid=$!
}

report() {  # COUNT
  local n=$1 s="$out/w$1/learner/summary.txt" reason wall steps upd t
  if [ ! -r "$s" ]; then
    printf '%8d  no summary: see %s\n' "$n" "$out/w$n/learner.log"
    return
  fi
  reason=$(sed -n 's/^stopped because *//p' "$s")
  wall=$(sed -n 's/^wall time *\([0-9.]*\) s.*/\1/p' "$s")
  steps=$(sed -n 's/^env steps *\([0-9]*\).*/\1/p' "$s")
  upd=$(sed -n 's/^updates *\([0-9]*\).*/\1/p' "$s")
  t=$(sed -n 's/.*asked at \([0-9.]*\) s).*/\1/p' <<<"$reason")
  case "$reason" in
    *"reached the target"*) t=$wall ;;
    *"goal reached"*) ;;
    *) t="-" ;;  # stopped on a limit: the goal was not reached
  esac
  # Batches lost / invalid and evaluations lost / invalid, from the summary's account lines.
  b=$(sed -n 's/^batches *ok [0-9]*, lost \([0-9]*\), duplicate [0-9]*, invalid \([0-9]*\).*/\1\/\2/p' "$s")
  e=$(sed -n 's/^evaluations *asked [0-9]*, answered [0-9]*, lost \([0-9]*\), invalid \([0-9]*\).*/\1\/\2/p' "$s")
  printf '%8d %14s %10s %12s %10s %10s %8s %9s %9s  %s\n' "$n" "$t" "$wall" "$steps" "$upd" \
    "$(awk -v u="$upd" -v w="$wall" 'BEGIN{printf "%.0f", u / w}')" \
    "$(awk -v u="$upd" -v e="$steps" 'BEGIN{printf "%.4f", u / e}')" "${b:-?}" "${e:-?}" "$reason"
}

pids=() slots=() k=0
for n in "${list[@]}"; do
  # Wait for a free slot: slot s is busy while pids[s] runs.
  while :; do
    for s in $(seq 0 $((parallel - 1))); do
      if [ -z "${pids[$s]:-}" ] || ! kill -0 "${pids[$s]}" 2>/dev/null; then
        start_run "$n" "$s" "$k"
        pids[$s]=$last_pid
        slots+=("$s")
        k=$((k + 1))
        continue 3
      fi
    done
    sleep 1
  done
done
wait
printf '%8s %14s %10s %12s %10s %10s %8s %9s %9s  %s\n' workers "time to goal" "wall [s]" "env steps" updates \
  "updates/s" "UTD" "b lost/inv" "e lost/inv" "stop reason"
for n in "${list[@]}"; do report "$n"; done
