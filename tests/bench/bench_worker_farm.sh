#!/usr/bin/env bash
# Workers in a real training run against the raw mj_step limit of the same host: first the limit
# (bench_worker --raw-only: WORKERS loops at once, each mj_step alone over states the config's
# task visits, in the ENVS simulations a worker holds; the env steps/s of each and their mean,
# with the older one-resting-state figure beside it), then one farm-learner with CONFIG and WORKERS
# farm-workers (one thread each) for SECONDS, and per worker its env steps/s from its throughput
# lines, set against the per-loop limit. Only lines in state `running` count, and none from a
# worker's first WARMUP_SECONDS of running.
#   tests/bench/bench_worker_farm.sh LEARNER_BIN WORKER_BIN CONFIG WORKERS SECONDS [ENVS]
# e.g. tests/bench/bench_worker_farm.sh build/learner/farm-learner build/worker/farm-worker \
#        deploy/configs/a1_ppo.txtpb 15 120
# ENVS: each worker's --envs (default: the config's worker.envs_per_worker).
# Environment: BENCH_WORKER_BIN (default: tests/bench_worker in the learner's build folder),
# WARMUP_SECONDS (default 5), RAW_SECONDS (default 3), DOMAIN (default 20 + pid mod 200),
# FARM_KEEP_LOGS=1 keeps the folder with the logs.
# Exit status: 0 when every worker reached 0.9 of the limit, 1 when one did not, 2 on an error.
set -euo pipefail

usage() {
  echo "usage: $0 LEARNER_BIN WORKER_BIN CONFIG WORKERS SECONDS [ENVS]" >&2
  exit 2
}
[ $# -ge 5 ] && [ $# -le 6 ] || usage
learner=$1 worker=$2 config=$3 workers=$4 seconds=$5 envs=${6:-}
bench=${BENCH_WORKER_BIN:-$(dirname "$(dirname "$learner")")/tests/bench_worker}
warmup=${WARMUP_SECONDS:-5}
raw_seconds=${RAW_SECONDS:-3}
domain=${DOMAIN:-$((20 + $$ % 200))}
die() {
  echo "bench_worker_farm: $*" >&2
  exit 2
}
for b in "$learner" "$worker" "$bench"; do [ -x "$b" ] || die "'$b' is not an executable program"; done
[ -r "$config" ] || die "cannot read config '$config'"
[[ "$workers" =~ ^[1-9][0-9]*$ ]] && [ "$workers" -le 256 ] || die "WORKERS must be an integer in 1..256, got '$workers'"
[[ "$seconds" =~ ^[1-9][0-9]*$ ]] || die "SECONDS must be a positive integer, got '$seconds'"
[ -z "$envs" ] || [[ "$envs" =~ ^[1-9][0-9]*$ ]] || die "ENVS must be a positive integer, got '$envs'"
[[ "$warmup" =~ ^[0-9]+$ ]] || die "WARMUP_SECONDS must be a whole number of seconds, got '$warmup'"
[[ "$raw_seconds" =~ ^[1-9][0-9]*$ ]] || die "RAW_SECONDS must be a positive integer, got '$raw_seconds'"
[[ "$domain" =~ ^[0-9]+$ ]] && [ "$domain" -le 232 ] || die "DOMAIN must be a DDS domain id in 0..232, got '$domain'"

dir=$(mktemp -d /tmp/farm-bench-worker-farm-XXXXXX)
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill -9 "$p" 2>/dev/null || true; done
  wait 2>/dev/null || true
  if [ -n "${FARM_KEEP_LOGS:-}" ]; then echo "logs kept in $dir"; else rm -rf "$dir"; fi
}
trap cleanup EXIT

echo "host: $(nproc) cores, load average $(cut -d' ' -f1-3 /proc/loadavg) before the run"

# 1. The limit: WORKERS raw loops at once, each what one single-threaded worker could reach.
"$bench" --config "$config" --raw-only --threads "$workers" --seconds "$raw_seconds" ${envs:+--envs "$envs"} \
  | tee "$dir/raw.txt"
limit=$(sed -n 's/^raw per loop ([0-9]* at once): \([0-9.]*\) env steps\/s$/\1/p' "$dir/raw.txt")
[ -n "$limit" ] || die "bench_worker printed no per-loop figure"

# 2. The training run. Each worker line gets the time it was printed (the worker's lines carry none).
stamp() { while IFS= read -r line; do printf '%s %s\n' "$EPOCHREALTIME" "$line"; done; }
"$learner" --config "$config" --run-dir "$dir/run" --domain "$domain" >"$dir/learner.log" 2>&1 &
pids+=($!)
learner_pid=$!
worker_pids=()
for i in $(seq 1 "$workers"); do
  "$worker" --domain "$domain" --id "bench-$i" --threads 1 --log-every 1 ${envs:+--envs "$envs"} \
    > >(stamp >"$dir/worker-$i.log") 2>&1 &
  pids+=($!)
  worker_pids+=($!)
done
echo "learner and $workers workers on DDS domain $domain for $seconds s ..."
# A learner that stops by itself (a stop rule of CONFIG) ends the measurement there.
for s in $(seq 1 "$seconds"); do
  sleep 1
  kill -0 "$learner_pid" 2>/dev/null || break
done
t_stop=$EPOCHREALTIME
load_during=$(cut -d' ' -f1-3 /proc/loadavg)
if ! kill -0 "$learner_pid" 2>/dev/null; then
  python3 -c '
import json, sys
print("stopped because", [e for e in map(json.loads, open(sys.argv[1])) if e.get("event") == "stop"][-1]["reason"])
' "$dir/run/events.jsonl" 2>/dev/null || tail -n 5 "$dir/learner.log"
  echo "the learner ended after about $s s: the measurement ends there"
fi
# Workers first (each sends what it holds and closes its stream), then the learner.
for p in "${worker_pids[@]}"; do kill -TERM "$p" 2>/dev/null || true; done
for p in "${worker_pids[@]}"; do
  for _ in $(seq 100); do kill -0 "$p" 2>/dev/null || break; sleep 0.2; done
done
kill -TERM "$learner_pid" 2>/dev/null || true
for _ in $(seq 150); do kill -0 "$learner_pid" 2>/dev/null || break; sleep 0.2; done
sleep 0.5  # the last stamped lines

# 3. Per worker: the mean of its running lines after warm-up, against the per-loop limit.
echo "host: load average $load_during at the end of the run"
printf '%-10s %12s %12s %7s %6s  %s\n' worker "env steps/s" "limit/loop" ratio lines \
  "collect: simulate+infer, backpressure, throttled; sender: publish (means); states after warm-up"
summary=()
for i in $(seq 1 "$workers"); do
  row=$(awk -v limit="$limit" -v warmup="$warmup" -v stop="$t_stop" '
    # <time> [worker ID] STATE: N steps/s (collect: simulate A%, infer B%, backpressure C%, throttled D%; sender: publish E%), ...
    $2 == "[worker" && $4 ~ /:$/ && $6 == "steps/s" {
      t = $1 + 0; state = substr($4, 1, length($4) - 1)
      if (t <= stop) seen[state]++
      if (state == "running" && first == "") first = t
      if (first == "" || t < first + warmup || t > stop) next
      states[state]++
      if (state != "running" || $7 != "(collect:") next
      n++; rate += $5
      gsub(/[%,;)]/, "")
      sim += $9 + $11; bp += $13; thr += $15; pub += $18
    }
    END {
      s = ""
      for (k in states) s = s (s == "" ? "" : ", ") k " " states[k]
      if (s == "") for (k in seen) s = s (s == "" ? "" : ", ") k " " seen[k]
      if (s == "") s = "none"
      if (n == 0) { printf "%12s %12.0f %7s %6d  no running line after warm-up (lines: %s)\n", "-", limit, "0.000", 0, s; exit }
      printf "%12.0f %12.0f %7.3f %6d  %.0f%%, %.0f%%, %.0f%%; %.0f%% | %s\n", rate / n, limit, rate / n / limit, n,
             sim / n, bp / n, thr / n, pub / n, s
    }' "$dir/worker-$i.log")
  printf '%-10s %s\n' "bench-$i" "$row"
  summary+=("$(awk '{print $3}' <<<"$row")")
done
printf '%s\n' "${summary[@]}" | awk '
  { r = $1 + 0; sum += r; if (NR == 1 || r < min) min = r }
  END {
    printf "min ratio %.3f, mean ratio %.3f: goal (min >= 0.9) %s\n", min, sum / NR, (min >= 0.9 ? "met" : "NOT met")
    if (min >= 0.9) exit 0
    exit 1
  }'
