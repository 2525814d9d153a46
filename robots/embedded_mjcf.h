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

// Compiles MJCF text given in memory, named `path` in errors (tests and benchmarks load edited
// copies of the embedded files with it). Throws std::runtime_error as above.
mjModel_* load_model_from_text(const std::string& path, const std::string& text);

}  // namespace farm::robots
