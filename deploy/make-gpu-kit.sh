#!/usr/bin/env bash
# Packs what a GPU host without Debian's packages needs to build the farm against its own CUDA
# LibTorch (deploy/build-gpu.sh) and to run the Debian-built benchmarks and workers there:
#   KIT/include, KIT/lib        headers and shared libraries of Eigen, Protobuf, MuJoCo (with
#                               libccd, lodepng, qhull_r, tinyxml2), Fast DDS, GoogleTest,
#                               civetweb, prometheus-cpp's core, OpenSSL's libcrypto, and the
#                               headers of CLI11 and nlohmann-json
#   KIT/cmake/<pkg>             small package configs pointing into the kit
#   KIT/bin/protoc              Debian's protoc (runs with KIT/lib on LD_LIBRARY_PATH)
#   KIT/bin/fastddsgen          stands in for fastddsgen (Java): copies the sources generated
#                               here from idl/farm.idl, after checking the IDL is unchanged
#   KIT/debian-bin              farm-worker, the policy measures (farm-mclari-eval, farm-mobile-eval) and
#                               the benchmark programs built here (optional)
# Usage (on the Debian machine, after a build):  deploy/make-gpu-kit.sh KIT [BUILD_DIR]
# The GPU host needs glibc >= 2.36 (Debian 12's) and libstdc++ from g++ >= 12.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
kit=${1:?usage: make-gpu-kit.sh KIT [BUILD_DIR]}
build=${2:-$root/build}
arch=/usr/lib/x86_64-linux-gnu
rm -rf "$kit"
mkdir -p "$kit"/{include,lib,bin,cmake,idl-gen,debian-bin}
kit=$(cd "$kit" && pwd)

for d in eigen3 google mujoco fastdds fastrtps fastcdr foonathan_memory gtest gmock; do
  cp -a /usr/include/$d "$kit/include/"
done
cp -a /usr/include/libqhull_r "$kit/include/" 2>/dev/null || true
# The task of terms' MJCF scan (tinyxml2) and reward expressions (muparser).
cp -a /usr/include/tinyxml2.h /usr/include/muParser*.h "$kit/include/"
# Multiarch headers (fastcdr/config.h, fastrtps/config.h).
cp -a /usr/include/x86_64-linux-gnu/fastcdr /usr/include/x86_64-linux-gnu/fastrtps "$kit/include/" 2>/dev/null || true
# Shared libraries with their soname links; GoogleTest is static.
for pat in 'libprotobuf.so*' 'libprotoc.so*' 'libmujoco.so*' 'libccd.so*' 'liblodepng.so*' \
           'libqhull_r.so*' 'libtinyxml2.so*' 'libfastrtps.so*' 'libfastcdr.so*' \
           'libfoonathan_memory*.so*' 'libgtest*.a' 'libgmock*.a' 'libmuparser.so*'; do
  cp -a $arch/$pat "$kit/lib/" 2>/dev/null || true
done
cp /usr/bin/protoc "$kit/bin/protoc"
# civetweb and prometheus-cpp's core (farm-monitor --prometheus) and OpenSSL's libcrypto (a worker
# reads its certificate's name): headers and libraries, found by tools/ and common/ through the
# kit's prefix (prometheus-cpp through its package config below).
cp -a /usr/include/civetweb.h /usr/include/prometheus "$kit/include/"
cp -a $arch/libcivetweb.so* $arch/libprometheus-cpp-core.so* "$kit/lib/"
cp -a /usr/include/openssl "$kit/include/"
cp -a /usr/include/x86_64-linux-gnu/openssl/* "$kit/include/openssl/" 2>/dev/null || true
cp -a $arch/libcrypto.so* "$kit/lib/"
# What Fast DDS links beside it (its security plugins, its persistence service): a bare host may
# lack them.
cp -a $arch/libssl.so* $arch/libsqlite3.so* "$kit/lib/"
# Header-only: CLI11 (every program's command-line options, common/cli.h) and nlohmann-json (the
# learner's events.jsonl).
cp -a /usr/include/CLI /usr/include/nlohmann "$kit/include/"

# IDL sources generated here (the GPU host has no Java for fastddsgen).
fastddsgen -replace -d "$kit/idl-gen" "$root/idl/farm.idl" >/dev/null
sha256sum "$root/idl/farm.idl" | cut -d' ' -f1 >"$kit/idl-gen/farm.idl.sha256"
cat >"$kit/bin/fastddsgen" <<'EOF'
#!/bin/sh
# Stand-in for fastddsgen on a host without Java: "fastddsgen -replace -d OUT IDL" copies the
# sources that deploy/make-gpu-kit.sh generated, if IDL is the file they came from.
set -e
gen=$(cd "$(dirname "$0")/../idl-gen" && pwd)
out=""; idl=""
while [ $# -gt 0 ]; do
  case "$1" in
    -d) out="$2"; shift 2 ;;
    -*) shift ;;
    *) idl="$1"; shift ;;
  esac
done
if [ "$(sha256sum "$idl" | cut -d' ' -f1)" != "$(cat "$gen/farm.idl.sha256")" ]; then
  echo "fastddsgen (kit): $idl changed since the kit was made; run deploy/make-gpu-kit.sh again" >&2
  exit 1
fi
mkdir -p "$out"
cp "$gen"/*.h "$gen"/*.cxx "$out/"
EOF
chmod +x "$kit/bin/fastddsgen"

# Package configs: imported targets with the names Debian's configs define.
imported() {  # name target lib [extra interface libs]
  mkdir -p "$kit/cmake/$1"
  cat >"$kit/cmake/$1/$1Config.cmake" <<EOF
get_filename_component(_kit "\${CMAKE_CURRENT_LIST_DIR}/../.." ABSOLUTE)
if(NOT TARGET $2)
  add_library($2 SHARED IMPORTED)
  set_target_properties($2 PROPERTIES IMPORTED_LOCATION "\${_kit}/lib/$3"
    INTERFACE_INCLUDE_DIRECTORIES "\${_kit}/include" INTERFACE_LINK_LIBRARIES "$4")
endif()
set($1_FOUND TRUE)
EOF
}
header_only() {  # package target: an INTERFACE target of Debian's name on the kit's headers
  mkdir -p "$kit/cmake/$1"
  cat >"$kit/cmake/$1/$1Config.cmake" <<EOF
get_filename_component(_kit "\${CMAKE_CURRENT_LIST_DIR}/../.." ABSOLUTE)
if(NOT TARGET $2)
  add_library($2 INTERFACE IMPORTED)
  set_target_properties($2 PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "\${_kit}/include")
endif()
set($1_FOUND TRUE)
EOF
}
header_only nlohmann_json nlohmann_json::nlohmann_json
header_only CLI11 CLI11::CLI11
imported mujoco mujoco::mujoco "$(readlink $arch/libmujoco.so)" ""
imported tinyxml2 tinyxml2::tinyxml2 "$(readlink $arch/libtinyxml2.so)" ""
imported muparser muparser::muparser "$(readlink $arch/libmuparser.so)" ""
imported prometheus-cpp prometheus-cpp::core "$(readlink $arch/libprometheus-cpp-core.so)" ""
imported fastcdr fastcdr "$(readlink $arch/libfastcdr.so)" ""
imported fastrtps fastrtps "$(readlink $arch/libfastrtps.so)" "fastcdr"
sed -i '1a include("${CMAKE_CURRENT_LIST_DIR}/../fastcdr/fastcdrConfig.cmake")' "$kit/cmake/fastrtps/fastrtpsConfig.cmake"
mkdir -p "$kit/cmake/Eigen3"
cat >"$kit/cmake/Eigen3/Eigen3Config.cmake" <<'EOF'
get_filename_component(_kit "${CMAKE_CURRENT_LIST_DIR}/../.." ABSOLUTE)
if(NOT TARGET Eigen3::Eigen)
  add_library(Eigen3::Eigen INTERFACE IMPORTED)
  set_target_properties(Eigen3::Eigen PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_kit}/include/eigen3")
endif()
set(Eigen3_FOUND TRUE)
set(Eigen3_VERSION 3.4.0)
EOF
mkdir -p "$kit/cmake/GTest"
cat >"$kit/cmake/GTest/GTestConfig.cmake" <<'EOF'
get_filename_component(_kit "${CMAKE_CURRENT_LIST_DIR}/../.." ABSOLUTE)
find_package(Threads REQUIRED)
foreach(_t gtest gtest_main gmock gmock_main)
  if(NOT TARGET GTest::${_t})
    add_library(GTest::${_t} STATIC IMPORTED)
    set_target_properties(GTest::${_t} PROPERTIES IMPORTED_LOCATION "${_kit}/lib/lib${_t}.a"
      INTERFACE_INCLUDE_DIRECTORIES "${_kit}/include" INTERFACE_LINK_LIBRARIES Threads::Threads)
  endif()
endforeach()
set_property(TARGET GTest::gtest_main APPEND PROPERTY INTERFACE_LINK_LIBRARIES GTest::gtest)
set(GTest_FOUND TRUE)
EOF

# Debian-built programs for hosts that only run them.
for b in worker/farm-worker tools/farm-mclari-eval tools/farm-mobile-eval tests/bench_worker tests/bench_transport tests/bench_scale \
         tests/farm_intruder; do
  [ -x "$build/$b" ] && cp "$build/$b" "$kit/debian-bin/"
done
cp "$root/deploy/fastdds_profiles.xml" "$kit/debian-bin/"
du -sh "$kit"
