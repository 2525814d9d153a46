#include "checkpoint.h"

#include <fcntl.h>
#include <ftw.h>
#include <google/protobuf/text_format.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>

#include <ctime>
#include <filesystem>
#include <fstream>
#include <sstream>

namespace farm {

namespace fs = std::filesystem;

namespace {

// fsync of one file or folder (a folder's fsync makes the renames and new names in it durable).
void sync_path(const fs::path& p) {
  const int fd = open(p.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) throw std::runtime_error("cannot open " + p.string() + " to sync it: " + std::strerror(errno));
  const int rc = fsync(fd);
  const int err = errno;
  close(fd);
  if (rc != 0) throw std::runtime_error("cannot sync " + p.string() + ": " + std::strerror(err));
}

// fsync of every file and folder under root, deepest first.
void sync_tree(const fs::path& root) {
  static thread_local std::string failed;
  failed.clear();
  auto one = [](const char* path, const struct stat*, int type, struct FTW*) {
    if (type != FTW_F && type != FTW_DP) return 0;
    try {
      sync_path(path);
    } catch (const std::exception& e) {
      failed = e.what();
      return 1;
    }
    return 0;
  };
  if (nftw(root.c_str(), one, 16, FTW_DEPTH | FTW_PHYS) != 0)
    throw std::runtime_error(failed.empty() ? "cannot walk " + root.string() + " to sync it" : failed);
}

}  // namespace

void write_checkpoint(const std::string& dir, const config::CheckpointManifest& manifest,
                      const std::function<void(const std::string& tmp_dir)>& write_parts) {
  const fs::path final_dir(dir), tmp = final_dir.string() + ".tmp", old = final_dir.string() + ".old";
  remove_tree(tmp);
  try {
    fs::create_directories(tmp);
    write_parts(tmp.string());
    std::string text;
    google::protobuf::TextFormat::PrintToString(manifest, &text);
    std::ofstream out(tmp / "manifest.txtpb");
    out << text;
    out.close();  // the check after the last flush: a full disk shows here
    if (!out) throw std::runtime_error("cannot write " + (tmp / "manifest.txtpb").string());
    // Every file and folder on disk before the rename makes them the checkpoint.
    sync_tree(tmp);
  } catch (...) {
    try {
      remove_tree(tmp);  // a half-written folder would only take the space the next try needs
    } catch (...) {
    }
    throw;
  }
  const fs::path parent = final_dir.has_parent_path() ? final_dir.parent_path() : fs::path(".");
  // DIR.old goes only while DIR is a whole checkpoint: after a crash between the renames, DIR.old is
  // the only one, and it stays until the new one is in place.
  if (fs::exists(final_dir / "manifest.txtpb")) {
    remove_tree(old);
    fs::rename(final_dir, old);
  } else if (fs::exists(final_dir)) {
    remove_tree(final_dir);
  }
  fs::rename(tmp, final_dir);
  sync_path(parent);  // the renames on disk before the previous checkpoint goes
  remove_tree(old);
  sync_path(parent);
}

// A crash between the two renames of a save leaves only DIR.old, which is complete: use it.
std::string usable_checkpoint(const std::string& dir) {
  if (!fs::exists(fs::path(dir) / "manifest.txtpb") && fs::exists(fs::path(dir + ".old") / "manifest.txtpb"))
    return dir + ".old";
  return dir;
}

config::CheckpointManifest read_manifest(const std::string& dir, const std::string& experiment_id) {
  const fs::path mpath = fs::path(usable_checkpoint(dir)) / "manifest.txtpb";
  std::ifstream in(mpath);
  if (!in) throw std::runtime_error("no checkpoint manifest at " + mpath.string());
  std::stringstream ss;
  ss << in.rdbuf();
  config::CheckpointManifest m;
  if (!google::protobuf::TextFormat::ParseFromString(ss.str(), &m))
    throw std::runtime_error("cannot parse checkpoint manifest " + mpath.string());
  if (m.experiment_id() != experiment_id)
    throw std::runtime_error(mpath.string() + ": checkpoint is of experiment '" + m.experiment_id() +
                             "', the config says '" + experiment_id + "'");
  return m;
}

std::string move_run_dir_aside(const std::string& run_dir) {
  if (!fs::exists(run_dir) || fs::is_empty(run_dir)) return "";
  const std::string aside = run_dir + "." + std::to_string(static_cast<long long>(std::time(nullptr)));
  fs::rename(run_dir, aside);
  return aside;
}

bool checkpoint_exists(const std::string& dir) {
  return fs::exists(fs::path(usable_checkpoint(dir)) / "manifest.txtpb");
}

}  // namespace farm
