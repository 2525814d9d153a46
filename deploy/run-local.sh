#!/usr/bin/env bash
# The main job on one host: installs what is missing, builds, then trains the default experiment
# with a learner and two workers talking over Fast DDS on this machine. Ends by itself with a
# summary; results in runs/<experiment>/ (learner.csv, summary.txt, checkpoint/), process output in runs/logs/.
#   deploy/run-local.sh [CONFIG] [WORKERS]
# Reachable from this host only: every process gets deploy/discovery/local.xml (shared memory is
# the only transport, no socket is opened), so nothing on the LAN can read the weights or send
# batches. FARM_DDS_PROFILES=FILE gives another profile (a farm over several hosts:
# docs/guides/hosts-and-security.md, which uses DDS Security).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
CONFIG="${1:-$ROOT/deploy/configs/pendulum_sac.txtpb}"
WORKERS="${2:-2}"
DOMAIN="${FARM_DOMAIN:-0}"
PROFILES="${FARM_DDS_PROFILES:-$ROOT/deploy/discovery/local.xml}"

"$ROOT/deploy/install-deps.sh"
# The main job runs the learner and the worker: it builds those (and what they link), nothing
# else; deploy/test.sh builds the rest.
"$ROOT/deploy/build.sh" farm-learner farm-worker
BIN="${FARM_BUILD_DIR:-$ROOT/build}"

cd "$ROOT"
LOGS="$ROOT/runs/logs"
mkdir -p "$LOGS"
pids=()
cleanup() { for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done; }
trap cleanup EXIT

# Workers first: they wait for the learner and say so.
for i in $(seq 1 "$WORKERS"); do
  "$BIN/worker/farm-worker" --domain "$DOMAIN" --dds-profiles "$PROFILES" --id "local-$i" > "$LOGS/worker-$i.log" 2>&1 &
  pids+=($!)
done
echo "run-local: $WORKERS workers started (logs in $LOGS/worker-*.log); starting the learner"
set +e
"$BIN/learner/farm-learner" --config "$CONFIG" --domain "$DOMAIN" --dds-profiles "$PROFILES" 2>&1 | tee "$LOGS/learner.log"
rc=${PIPESTATUS[0]}
set -e
for p in "${pids[@]}"; do wait "$p" 2>/dev/null || true; done
pids=()
tail -n 1 "$LOGS"/worker-*.log
exit "$rc"
