// MJCF files compiled into the binary (robots/CMakeLists.txt generates the table), so a worker
// on another host loads its robots without a source tree.
#pragma once

#include <string>
#include <vector>

struct mjModel_;

namespace farm::robots {

struct EmbeddedFile {
  const char* path;  // relative to robots/, e.g. "pendulum/pendulum.xml"
  const char* text;
};

const std::vector<EmbeddedFile>& embedded_mjcf();

// Compiles the embedded file at `path` (as listed in embedded_mjcf()). The caller owns the
// model (mj_deleteModel). Throws std::runtime_error naming the file and MuJoCo's error.
mjModel_* load_embedded_model(const std::string& path);

}  // namespace farm::robots
