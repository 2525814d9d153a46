// A MuJoCo model as data that travels: its MJCF and every file it names (includes, meshes, height
// fields, textures, skins), read at the learner from the model's own folder and shipped in the
// experiment config; and what the model holds (bodies, joints, actuators, sensors), read from the
// XML alone, so that the learner sizes a task of terms without MuJoCo.
//
// Nothing here opens a path that came from the bus: check_bundle() refuses a bundle whose files
// name an absolute path, "..", or a file that is not in the bundle, before MuJoCo sees it (MuJoCo's
// virtual file system would fall back to the disk for a name it lacks).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "farm_config.pb.h"

namespace farm::robots::terms {

// At most this many bytes of model files, whatever max_model_bytes asks for: a bound on what a
// spec from the bus makes a worker hold.
inline constexpr int64_t kMaxModelBytesCap = 64ll << 20;
// MuJoCo 2.2.2's virtual file system holds at most this many files.
inline constexpr int kMaxModelFiles = 2000;

struct ModelError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// Reads `model_path` and every file it names, recursively through includes, into cfg's
// model_files (paths relative to the model's folder; the model's own file first) and sets
// cfg.model to the model file's name. Throws ModelError naming the file that lies outside the
// folder, is missing, or pushes the total past max_model_bytes.
void read_model_folder(const std::string& model_path, config::TermsConfig* cfg);

// Checks a bundle as received (no disk is touched): cfg.model and every model_files path are
// relative and stay inside the folder, base names are unique (MuJoCo's VFS keys files by base name),
// the total is within max_model_bytes and kMaxModelBytesCap, and every file the MJCF names is in the
// bundle. Throws ModelError naming what is wrong.
void check_bundle(const config::TermsConfig& cfg);

// True for a relative path that stays inside its folder ("meshes/leg.stl"); false for an absolute
// one, one with a ".." component, a backslash or a NUL.
bool path_inside_folder(const std::string& path);

// What the model defines, in MuJoCo's order (bodies depth first, a body's joints before its
// children's), read from the MJCF text with its includes and default classes.
struct JointInfo {
  std::string name;
  std::string type;  // "free", "ball", "slide", "hinge"
  int qpos_size() const;
  int dof_size() const;
};
struct SensorInfo {
  std::string name;
  int dim = 0;
};
struct ModelInfo {
  std::vector<std::string> bodies;  // the world (body 0, "world") first
  std::vector<JointInfo> joints;
  std::vector<std::string> geoms;
  std::vector<std::string> actuators;
  std::vector<std::string> actuator_joints;  // the joint each actuator drives ("" for others)
  std::vector<SensorInfo> sensors;
  std::vector<std::string> keyframes;
  int nq() const;
  int nv() const;
};

// Reads the bundle's model (check_bundle() first). Throws ModelError naming the file and element
// it cannot read.
ModelInfo scan_model(const config::TermsConfig& cfg);

}  // namespace farm::robots::terms
