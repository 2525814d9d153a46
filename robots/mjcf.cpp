#include <mujoco/mujoco.h>

#include <cstring>
#include <memory>
#include <stdexcept>

#include "embedded_mjcf.h"

namespace farm::robots {

namespace {

std::string known_files() {
  std::string s;
  for (const auto& f : embedded_mjcf()) s += (s.empty() ? "" : ", ") + std::string(f.path);
  return s;
}

// mjVFS holds its file-name table inline (megabytes), too big for a thread's stack.
struct VfsDeleter {
  void operator()(mjVFS* v) const {
    mj_deleteVFS(v);
    delete v;
  }
};

}  // namespace

mjModel* load_embedded_model(const std::string& path) {
  const EmbeddedFile* file = nullptr;
  for (const auto& f : embedded_mjcf()) {
    if (path == f.path) file = &f;
  }
  if (!file) {
    throw std::runtime_error("MJCF '" + path + "' is not embedded; embedded files: " + known_files());
  }
  return load_model_from_text(path, file->text);
}

mjModel* load_model_from_text(const std::string& path, const std::string& text) {
  // The VFS keys files by name without directories; models that include other files would
  // need every embedded file registered under its base name.
  const std::string name = path.substr(path.find_last_of('/') + 1);
  std::unique_ptr<mjVFS, VfsDeleter> vfs(new mjVFS);
  mj_defaultVFS(vfs.get());
  const int size = int(text.size());
  if (mj_makeEmptyFileVFS(vfs.get(), name.c_str(), size) != 0) {
    throw std::runtime_error("MJCF '" + path + "': could not add it to MuJoCo's VFS");
  }
  const int index = mj_findFileVFS(vfs.get(), name.c_str());
  if (index < 0) {
    throw std::runtime_error("MJCF '" + path + "': not found in MuJoCo's VFS after adding it");
  }
  std::memcpy(vfs->filedata[index], text.data(), size);

  char err[1000] = "";
  mjModel* m = mj_loadXML(name.c_str(), vfs.get(), err, sizeof err);
  if (!m) throw std::runtime_error("MJCF '" + path + "': " + (err[0] ? err : "load failed"));
  return m;
}

}  // namespace farm::robots
