#!/usr/bin/env bash
# Builds the learner (farm-learner, bench_sac, bench_dqn, bench_ppo) against a CUDA LibTorch on a GPU host; the
# config's sac.device, dqn.device or ppo.device ("cpu" by default, "cuda", "cuda:N" or "auto") picks
# where it trains.
#
#   deploy/build-gpu.sh [BUILD_DIR]          (default: build-gpu)
#
# LibTorch: TORCH_CMAKE_PREFIX, else the one inside python3's PyTorch installation
#   (python3 -c 'import torch; print(torch.utils.cmake_prefix_path)').
# Other dependencies: installed (deploy/install-deps.sh), or, on a host where nothing can be
#   installed, a folder made by deploy/make-gpu-kit.sh on a Debian machine, given as FARM_GPU_KIT.
# FARM_WITH_DDS=OFF builds only the learner core and the benchmarks (no Fast DDS needed).
# FARM_GPU_TARGETS="bench_sac test_sac" builds just those targets instead of the default ones.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
build=${1:-$root/build-gpu}
torch_prefix=${TORCH_CMAKE_PREFIX:-$(python3 -c 'import torch; print(torch.utils.cmake_prefix_path)')}
with_dds=${FARM_WITH_DDS:-ON}
prefix="$torch_prefix"
args=()
if [ -n "${FARM_GPU_KIT:-}" ]; then
  kit=$(cd "$FARM_GPU_KIT" && pwd)
  prefix="$kit/cmake;$kit;$prefix"
  export LD_LIBRARY_PATH="$kit/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
  export PATH="$kit/bin:$PATH"
  args+=(-DProtobuf_PROTOC_EXECUTABLE="$kit/bin/protoc" -DProtobuf_INCLUDE_DIR="$kit/include"
         -DProtobuf_LIBRARY="$kit/lib/libprotobuf.so" -DFASTDDSGEN="$kit/bin/fastddsgen"
         -DCMAKE_BUILD_RPATH="$kit/lib")
fi
targets=(bench_sac bench_dqn bench_ppo)
[ "$with_dds" = ON ] && targets+=(farm-learner)
[ -n "${FARM_GPU_TARGETS:-}" ] && read -r -a targets <<<"$FARM_GPU_TARGETS"
# A CUDA compiler for the SAC graph's fused kernels: CUDACXX, else nvcc on PATH, else the toolkit's
# usual place; without one the graph keeps torch's ops (the build says so).
if [ -z "${CUDACXX:-}" ] && ! command -v nvcc >/dev/null && [ -x /usr/local/cuda/bin/nvcc ]; then
  export CUDACXX=/usr/local/cuda/bin/nvcc
fi
gen=()
command -v ninja >/dev/null && gen=(-G Ninja)
cmake -S "$root" -B "$build" "${gen[@]}" -DCMAKE_BUILD_TYPE=Release -DCMAKE_PREFIX_PATH="$prefix" \
  -DFARM_WITH_DDS="$with_dds" "${args[@]}"
cmake --build "$build" -j "$(nproc)" --target "${targets[@]}"
echo "built: ${targets[*]} in $build (set sac, dqn or ppo { device: \"cuda\" } in the experiment config)"
