// The checkpoint's atomic write (learner/checkpoint.h): a save that fails at any point leaves a
// usable checkpoint behind.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "checkpoint.h"

namespace fs = std::filesystem;

namespace {

struct TempDir {
  fs::path path = fs::temp_directory_path() / ("farm_checkpoint_" + std::to_string(::getpid()));
  TempDir() { fs::create_directories(path); }
  ~TempDir() { fs::remove_all(path); }
};

farm::config::CheckpointManifest manifest(uint64_t version) {
  farm::config::CheckpointManifest m;
  m.set_experiment_id("ckpt");
  m.set_policy_version(version);
  return m;
}

void save(const std::string& dir, uint64_t version) {
  farm::write_checkpoint(dir, manifest(version),
                         [&](const std::string& tmp) { std::ofstream(tmp + "/part.bin") << "v" << version; });
}

std::string part(const std::string& dir) {
  std::ifstream in(fs::path(farm::usable_checkpoint(dir)) / "part.bin");
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

TEST(Checkpoint, ASaveReplacesThePreviousOne) {
  TempDir t;
  const std::string dir = (t.path / "checkpoint").string();
  save(dir, 1);
  save(dir, 2);
  EXPECT_EQ(farm::read_manifest(dir, "ckpt").policy_version(), 2u);
  EXPECT_EQ(part(dir), "v2");
  EXPECT_FALSE(fs::exists(dir + ".old"));
  EXPECT_FALSE(fs::exists(dir + ".tmp"));
}

// A crash between a save's two renames leaves only DIR.old. The resumed learner's next save must not
// remove it before its own checkpoint is in place: here that save's last rename fails (DIR is a link
// to nowhere, which exists() does not see and rename() cannot replace by a folder), and DIR.old is
// still the checkpoint. Before, DIR.old was removed first and nothing usable was left.
TEST(Checkpoint, TheOnlyCheckpointLeftByACrashSurvivesAFailedSave) {
  TempDir t;
  const std::string dir = (t.path / "checkpoint").string();
  save(dir, 1);
  fs::rename(dir, dir + ".old");
  ASSERT_TRUE(farm::checkpoint_exists(dir));
  EXPECT_EQ(farm::usable_checkpoint(dir), dir + ".old");
  fs::create_symlink(t.path / "nowhere", dir);
  EXPECT_ANY_THROW(save(dir, 2));
  ASSERT_TRUE(farm::checkpoint_exists(dir));
  EXPECT_EQ(farm::read_manifest(dir, "ckpt").policy_version(), 1u);
  EXPECT_EQ(part(dir), "v1");

  // Once DIR can be written, the next save takes its place and DIR.old goes.
  fs::remove(dir);
  save(dir, 3);
  EXPECT_EQ(farm::read_manifest(dir, "ckpt").policy_version(), 3u);
  EXPECT_EQ(farm::usable_checkpoint(dir), dir);
  EXPECT_FALSE(fs::exists(dir + ".old"));
}

}  // namespace
