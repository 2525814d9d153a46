#!/usr/bin/env bash
# Builds farm-learner against the GPU host's CUDA LibTorch and runs training seeds of an
# off-policy config with tests/bench/bench_seeds.sh, in one call.
#   tools/gpu-offpolicy-train.sh CONFIG "SEEDS" "WORKER COUNTS" [OUT_DIR]   (default: runs/gpu-train)
# Needs a full kit from deploy/make-gpu-kit.sh (Fast DDS included) in gpukit-full/ (FARM_GPU_KIT
# overrides), or its archive gpukit-full.tar.xz, unpacked there first (the archive is a fifth of the
# kit's size to carry). STOP, SET_BLOCK and SET_LINES pass to bench_seeds.sh.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
config=${1:?usage: gpu-offpolicy-train.sh CONFIG SEEDS COUNTS [OUT_DIR]} seeds=${2:?} counts=${3:?}
out=${4:-$root/runs/gpu-train}
mkdir -p "$out"
export FARM_GPU_KIT=${FARM_GPU_KIT:-$root/gpukit-full} OMP_WAIT_POLICY=PASSIVE
if [ ! -d "$FARM_GPU_KIT/lib" ] && [ -f "$FARM_GPU_KIT.tar.xz" ]; then
  mkdir -p "$FARM_GPU_KIT"
  tar -xJf "$FARM_GPU_KIT.tar.xz" --strip-components=1 -C "$FARM_GPU_KIT"
fi
export LD_LIBRARY_PATH="$FARM_GPU_KIT/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee "$out/gpu.txt"
# The worker is built there too, from the same sources as the learner; where that fails, the
# kit's Debian-built one runs (it speaks the same wire types only if the kit is as new as the tree).
worker="$root/build-gpu/worker/farm-worker"
if ! FARM_GPU_TARGETS="farm-learner farm-worker" "$root/deploy/build-gpu.sh" "$root/build-gpu" >"$out/build.log" 2>&1; then
  FARM_GPU_TARGETS=farm-learner "$root/deploy/build-gpu.sh" "$root/build-gpu" >>"$out/build.log" 2>&1 ||
    { tail -40 "$out/build.log"; exit 1; }
  worker="$FARM_GPU_KIT/debian-bin/farm-worker"
  echo "gpu-offpolicy-train: farm-worker did not build here (build.log); the kit's runs" | tee "$out/worker.txt"
fi
"$root/tests/bench/bench_seeds.sh" "$root/build-gpu/learner/farm-learner" "$worker" \
  "$config" "$seeds" "$counts" "$out/seeds" 2>&1 | tee "$out/bench_seeds.txt"
# Each run's files one level up (a caller that fetches only shallow paths still gets them), and
# the first worker's last lines where a run got no env steps.
for run in "$out"/seeds/seed*/w*; do
  [ -d "$run" ] || continue
  tag=$(basename "$(dirname "$run")")_$(basename "$run")
  for f in learner/learner.csv learner/summary.txt learner/events.jsonl learner.log worker-1.log; do
    [ -f "$run/$f" ] && cp "$run/$f" "$out/${tag}_$(basename "$f")"
  done
  if ! grep -q '^env steps *[1-9]' "$run/learner/summary.txt" 2>/dev/null; then
    echo "== $tag: no env steps; worker-1.log ends:"
    tail -15 "$run/worker-1.log" 2>/dev/null || echo "(no worker log)"
  fi
done
