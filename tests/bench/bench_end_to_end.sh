#!/usr/bin/env bash
# End to end: wall time from start to the config's target evaluation return, for a learner and
# 1, 2, 4, ... workers on this host (fresh run each, same seed).
#   tests/bench/bench_end_to_end.sh LEARNER_BIN WORKER_BIN CONFIG "1 2 4" [RUN_ROOT] [WORKER_FLAGS]
# Prints one line per worker count: seconds, the stop reason, env steps and updates at the end.
set -euo pipefail
learner=$1; worker=$2; config=$3; counts=${4:-"1 2 4"}
root=${5:-/tmp/farm_e2e}
worker_flags=${6:-}
mkdir -p "$root"
printf '%8s %10s  %s\n' workers seconds "stop reason | summary"
for n in $counts; do
  domain=$((100 + n))
  run="$root/w$n"
  rm -rf "$run"; mkdir -p "$run"
  pids=()
  for i in $(seq 1 "$n"); do
    "$worker" --domain "$domain" --id "e2e-$i" $worker_flags >"$run/worker-$i.log" 2>&1 &
    pids+=($!)
  done
  t0=$(date +%s.%N)
  set +e
  "$learner" --config "$config" --domain "$domain" --run-dir "$run/learner" >"$run/learner.log" 2>&1
  rc=$?
  set -e
  t1=$(date +%s.%N)
  for p in "${pids[@]}"; do wait "$p" 2>/dev/null || kill "$p" 2>/dev/null || true; done
  # The learner's summary event (RUN/events.jsonl): why it stopped, env steps and updates.
  ended=$(python3 -c '
import json, sys
s = [e for e in map(json.loads, open(sys.argv[1])) if e.get("event") == "summary"][-1]
print("stopped because %s | env steps %d | updates %d" % (s["reason"], s["env_steps"], s["updates"]))
' "$run/learner/events.jsonl" 2>/dev/null || echo "rc $rc")
  printf '%8d %10.1f  %s\n' "$n" "$(awk "BEGIN{print $t1 - $t0}")" "$ended"
done
