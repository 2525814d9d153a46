#!/usr/bin/env bash
# Installs the Debian 12 packages the farm needs, only those missing. Safe to run twice.
set -euo pipefail

PACKAGES=(
  build-essential cmake ninja-build pkg-config
  libfastrtps-dev fastddsgen fastdds-tools          # Fast DDS 2.9 and its IDL generator
  libmujoco-dev libqhull-dev                        # MuJoCo 2.2.2 (its CMake target needs qhull)
  libgl-dev libopengl-dev libglx-dev                # ... and OpenGL (find_dependency in mujocoConfig.cmake)
  libeigen3-dev libprotobuf-dev protobuf-compiler
  libtinyxml2-dev libmuparser-dev                   # the task of terms: its MJCF scan and reward expressions
  nlohmann-json3-dev                                # the learner's RUN/events.jsonl
  libtorch-dev libopenblas0-pthread                 # without OpenBLAS LibTorch is ~6x slower
  libgtest-dev libbenchmark-dev
  zlib1g-dev python3-matplotlib                   # mCLARI height-field PNG, sweep plots
  clang libclang-rt-14-dev openssl                  # fuzz targets (libFuzzer); DDS Security PKI
  iproute2                                          # the several-hosts test: network namespaces, veth
  clang-format                                      # the format check (deploy/format.sh --check)
  libosmesa6-dev ffmpeg                             # farm-play: headless MuJoCo rendering, MP4/GIF
  libonnx-dev python3-onnx python3-opencv           # farm-export: ONNX schema/checker; OpenCV DNN cross-check
  libcivetweb-dev prometheus-cpp-dev prometheus     # farm-monitor --prometheus (HTTP, metrics) and its scrape test
  faketime                                          # the security test's worker on a clock an hour behind
  libcli11-dev                                      # every program's command-line options (header-only)
  pybind11-dev python3-dev python3-numpy            # the Python package farm (python/)
  python3-pytest python3-pandas python3-torch       # ... its tests, runs as DataFrames, the PyTorch example
)

missing=()
for p in "${PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#PACKAGES[@]} packages present"
  exit 0
fi

# Debian's prometheus package is here for its binaries (the scrape test runs its own server on
# 127.0.0.1). Installed alone, without its recommended node exporter, and the service its package
# starts is stopped and disabled: the install leaves nothing listening that the user did not ask
# for. A prometheus installed before is left as it was.
rest=()
server=0
for p in "${missing[@]}"; do
  if [ "$p" = prometheus ]; then server=1; else rest+=("$p"); fi
done

SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
echo "install-deps: installing ${missing[*]}"
$SUDO apt-get update -q
if [ ${#rest[@]} -gt 0 ]; then DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q "${rest[@]}"; fi
if [ $server = 1 ]; then
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q --no-install-recommends prometheus
  if [ -d /run/systemd/system ]; then
    $SUDO systemctl disable --now prometheus.service
    echo "install-deps: the prometheus service Debian started is stopped and disabled (the tests run their own)"
  fi
fi
