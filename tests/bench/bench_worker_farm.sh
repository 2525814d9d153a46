#!/usr/bin/env bash
# Workers in a real training run against the raw mj_step limit of the same host: first the limit
# (bench_worker --raw-only: WORKERS loops at once, each mj_step alone over states the config's
# task visits, in the ENVS simulations a worker holds; the env steps/s of each and their mean,
# with the older one-resting-state figure beside it), then one farm-learner with CONFIG and WORKERS
# farm-workers (one thread each) for SECONDS, and per worker its env steps/s from its progress
# events (--events, one a second), set against the per-loop limit. Only events in state `running`
# count, and none from a worker's first WARMUP_SECONDS of running.
#   tests/bench/bench_worker_farm.sh LEARNER_BIN WORKER_BIN CONFIG WORKERS SECONDS [ENVS]
# e.g. tests/bench/bench_worker_farm.sh build/learner/farm-learner build/worker/farm-worker \
#        deploy/configs/a1_ppo.txtpb 15 120
# ENVS: each worker's --envs (default: the config's worker.envs_per_worker).
# Environment: BENCH_WORKER_BIN (default: tests/bench_worker in the learner's build folder),
# WARMUP_SECONDS (default 5), RAW_SECONDS (default 3), DOMAIN (default 20 + pid mod 200),
# FARM_KEEP_LOGS=1 keeps the folder with the logs and events.
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

# 2. The training run.
"$learner" --config "$config" --run-dir "$dir/run" --domain "$domain" >"$dir/learner.log" 2>&1 &
pids+=($!)
learner_pid=$!
worker_pids=()
for i in $(seq 1 "$workers"); do
  "$worker" --domain "$domain" --id "bench-$i" --threads 1 --log-every 1 ${envs:+--envs "$envs"} \
    --events "$dir/worker-$i.jsonl" >"$dir/worker-$i.log" 2>&1 &
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

# 3. Per worker: the mean of its running events after warm-up, against the per-loop limit.
# One worker's row from its progress events (worker/worker_app.h): those up to STOP (Unix seconds,
# the measurement's end) by state; from WARMUP s after its first `running` one, the running ones
# with a time split (not the first) give the means. "STEPS/S LIMIT RATIO EVENTS  SHARES | STATES".
worker_row() {  # EVENTS LIMIT WARMUP STOP
  python3 - "$@" <<'PY'
import json, sys
path, limit, warmup, stop = sys.argv[1], float(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4])
try:
    lines = open(path, errors="replace").readlines()
except OSError:
    lines = []
seen, states, first = {}, {}, None
n = rate = sim = bp = thr = pub = 0
for line in lines:
    try:
        e = json.loads(line)
    except ValueError:
        continue  # a line cut short by a killed worker
    if e.get("event") != "progress":
        continue
    t, state = e["unix_s"], e["state"]
    if t <= stop:
        seen[state] = seen.get(state, 0) + 1
    if state == "running" and first is None:
        first = t
    if first is None or t < first + warmup or t > stop:
        continue
    states[state] = states.get(state, 0) + 1
    if state != "running" or e.get("simulate") is None:
        continue
    n += 1
    rate += e["steps_per_s"]
    sim += e["simulate"] + e["infer"]
    bp += e["backpressure"]
    thr += e["throttled"]
    pub += e["publish"]
s = ", ".join(f"{k} {v}" for k, v in (states or seen).items()) or "none"
if n == 0:
    print("%12s %12.0f %7s %6d  no running line after warm-up (lines: %s)" % ("-", limit, "0.000", 0, s))
else:
    print("%12.0f %12.0f %7.3f %6d  %.0f%%, %.0f%%, %.0f%%; %.0f%% | %s" % (rate / n, limit, rate / n / limit, n,
          100 * sim / n, 100 * bp / n, 100 * thr / n, 100 * pub / n, s))
PY
}
echo "host: load average $load_during at the end of the run"
printf '%-10s %12s %12s %7s %6s  %s\n' worker "env steps/s" "limit/loop" ratio lines \
  "collect: simulate+infer, backpressure, throttled; sender: publish (means); states after warm-up"
summary=()
for i in $(seq 1 "$workers"); do
  row=$(worker_row "$dir/worker-$i.jsonl" "$limit" "$warmup" "$t_stop")
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
