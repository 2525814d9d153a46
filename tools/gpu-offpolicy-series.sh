#!/usr/bin/env bash
# Builds the off-policy benchmark against the GPU host's CUDA LibTorch and runs the large-batch
# series of issue "off-policy at the swarm's scale" in one call: each off-policy algorithm's
# updates/s and samples/s (batch x updates/s) at batches 256, 4,096 and 32,768 for 256-256 and
# 512-512-512 networks, through the interface the learner runs them by (tests/bench/bench_offpolicy.cpp);
# SAC and DQN each with their matrix products in float32 and in bfloat16 (DQN with its minibatches
# drawn on the GPU, dqn.replay_on_device, its default there).
#   tools/gpu-offpolicy-series.sh [OUT_DIR]      (default: runs/gpu-series)
# SERIES_SECONDS (default 2) is the time measured per figure; SERIES_ARGS are added to
# bench_offpolicy's (e.g. --algorithms sac). Needs a kit from deploy/make-gpu-kit.sh in gpukit/
# (FARM_GPU_KIT overrides) on a host without the Debian packages; the learner core is built
# without Fast DDS unless FARM_WITH_DDS=ON (a full kit: the build folder of
# tools/gpu-offpolicy-train.sh is then reused as it is).
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
out=${1:-$root/runs/gpu-series}
mkdir -p "$out"
export FARM_GPU_KIT=${FARM_GPU_KIT:-$root/gpukit} FARM_WITH_DDS=${FARM_WITH_DDS:-OFF}
export FARM_GPU_TARGETS=${FARM_GPU_TARGETS:-bench_offpolicy} OMP_WAIT_POLICY=PASSIVE
export LD_LIBRARY_PATH="$FARM_GPU_KIT/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee "$out/gpu.txt"
"$root/deploy/build-gpu.sh" "$root/build-gpu" >"$out/build.log" 2>&1 || { tail -40 "$out/build.log"; exit 1; }
# shellcheck disable=SC2086  # SERIES_ARGS are words
"$root/build-gpu/tests/bench_offpolicy" --device cuda --algorithms sac,td3,dqn \
  --batches 256,4096,32768 --hidden-sets "256,256;512,512,512" \
  --variant 'sac:matmul_dtype: "float32"' --variant 'sac:matmul_dtype: "bfloat16"' \
  --variant 'dqn:matmul_dtype: "float32"' --variant 'dqn:matmul_dtype: "bfloat16"' \
  --seconds "${SERIES_SECONDS:-2}" ${SERIES_ARGS:-} 2>&1 | tee "$out/bench_offpolicy.txt"
