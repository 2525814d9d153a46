// remove_dead_segments: a Fast DDS data segment whose lock file no process holds, and that is old
// enough, goes with its lock file; one whose lock is held, a young one, ports and other names stay;
// removed_by_this_process sums what every call removed.
// Locks are real flocks on real files (a second open file description conflicts like another
// process would); integration.restart_ports does the same with a SIGKILLed worker's segment.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/file.h>
#include <sys/time.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>

#include "shm_leftovers.h"

namespace fs = std::filesystem;
using farm::dds::remove_dead_segments;

namespace {

struct ShmDir : ::testing::Test {
  fs::path dir;
  void SetUp() override {
    char tmpl[] = "/tmp/farm_shm_test_XXXXXX";
    ASSERT_NE(mkdtemp(tmpl), nullptr);
    dir = tmpl;
  }
  void TearDown() override { fs::remove_all(dir); }

  // A file of `bytes` bytes whose modification time is `age` seconds ago.
  fs::path make(const std::string& name, size_t bytes, double age) {
    const fs::path p = dir / name;
    std::ofstream(p) << std::string(bytes, 'x');
    timeval tv[2];
    gettimeofday(&tv[0], nullptr);
    tv[0].tv_sec -= long(age);
    tv[1] = tv[0];
    EXPECT_EQ(utimes(p.c_str(), tv), 0);
    return p;
  }
};

TEST_F(ShmDir, DeadOldSegmentGoesLiveYoungPortsAndOthersStay) {
  // Dead and old: goes.
  const fs::path dead = make("fastrtps_0123456789abcdef", 65536, 120);
  const fs::path dead_lock = make("fastrtps_0123456789abcdef_el", 0, 120);
  // Old, its lock held (as the living owner holds it): stays.
  const fs::path live = make("fastrtps_a1b2c3d4e5f60718", 4096, 120);
  const fs::path live_lock = make("fastrtps_a1b2c3d4e5f60718_el", 0, 120);
  const int held = open(live_lock.c_str(), O_RDWR);
  ASSERT_GE(held, 0);
  ASSERT_EQ(flock(held, LOCK_EX | LOCK_NB), 0);
  // Unlocked but young (a process may be about to lock it): stays.
  const fs::path young = make("fastrtps_ffffffffffffffff", 4096, 0);
  const fs::path young_lock = make("fastrtps_ffffffffffffffff_el", 0, 0);
  // A dead process's port: stays (a live peer may still write into it).
  const fs::path port = make("fastrtps_port7413", 4096, 120);
  const fs::path port_lock = make("fastrtps_port7413_el", 0, 120);
  // Not a segment's lock: other lengths, upper case, another suffix.
  const fs::path other1 = make("fastrtps_0123_el", 0, 120);
  const fs::path other2 = make("fastrtps_0123456789ABCDEF_el", 0, 120);
  const fs::path other3 = make("fastrtps_0123456789abcdef_xx", 0, 120);

  const auto gone = remove_dead_segments(dir.string(), 30.0);
  EXPECT_EQ(gone.segments, 1);
  EXPECT_GE(gone.bytes, 65536u);
  EXPECT_EQ(gone.in_use, 1);
  EXPECT_FALSE(fs::exists(dead));
  EXPECT_FALSE(fs::exists(dead_lock));
  for (const auto& p : {live, live_lock, young, young_lock, port, port_lock, other1, other2, other3})
    EXPECT_TRUE(fs::exists(p)) << p;

  // Once its owner is gone (the lock released), the other old one goes too; the young one still stays.
  close(held);
  const auto again = remove_dead_segments(dir.string(), 30.0);
  EXPECT_EQ(again.segments, 1);
  EXPECT_EQ(again.in_use, 0);
  EXPECT_FALSE(fs::exists(live));
  EXPECT_FALSE(fs::exists(live_lock));
  EXPECT_TRUE(fs::exists(young));
}

TEST_F(ShmDir, SharedLockCountsAsInUseAndLockWithoutSegmentIsTidied) {
  const fs::path seg = make("fastrtps_00000000000000aa", 4096, 120);
  const fs::path lock = make("fastrtps_00000000000000aa_sl", 0, 120);
  const int held = open(lock.c_str(), O_RDONLY);
  ASSERT_GE(held, 0);
  ASSERT_EQ(flock(held, LOCK_SH | LOCK_NB), 0);
  EXPECT_EQ(remove_dead_segments(dir.string(), 30.0).segments, 0);
  EXPECT_TRUE(fs::exists(seg));
  close(held);
  // A lock file whose segment is gone already: removed, counted as no segment.
  const fs::path orphan = make("fastrtps_00000000000000bb_el", 0, 120);
  const auto gone = remove_dead_segments(dir.string(), 30.0);
  EXPECT_EQ(gone.segments, 1);  // the _sl one, now unlocked
  EXPECT_FALSE(fs::exists(orphan));
  EXPECT_FALSE(fs::exists(seg));
}

// The process's sum (a worker's start event reports it) grows by what each call removed.
TEST_F(ShmDir, ThisProcessSumsWhatEveryCallRemoved) {
  const auto before = farm::dds::removed_by_this_process();
  make("fastrtps_00000000000000cc", 8192, 120);
  make("fastrtps_00000000000000cc_el", 0, 120);
  const auto gone = remove_dead_segments(dir.string(), 30.0);
  ASSERT_EQ(gone.segments, 1);
  EXPECT_EQ(remove_dead_segments(dir.string(), 30.0).segments, 0);
  const auto after = farm::dds::removed_by_this_process();
  EXPECT_EQ(after.segments, before.segments + 1);
  EXPECT_EQ(after.bytes, before.bytes + gone.bytes);
  EXPECT_EQ(after.in_use, 0);
}

TEST_F(ShmDir, MissingFolderRemovesNothing) {
  const auto gone = remove_dead_segments((dir / "absent").string(), 30.0);
  EXPECT_EQ(gone.segments, 0);
  EXPECT_EQ(gone.in_use, 0);
}

}  // namespace
