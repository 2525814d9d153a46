#include "shm_leftovers.h"

#include <dirent.h>
#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cctype>
#include <ctime>
#include <vector>

namespace farm::dds {
namespace {

std::atomic<int> g_removed_segments{0};
std::atomic<uint64_t> g_removed_bytes{0};

// fastrtps_ + 16 lower-case letters or digits + _el or _sl: a data segment's lock file.
bool is_segment_lock(const std::string& name) {
  static const std::string prefix = "fastrtps_";
  if (name.size() != prefix.size() + 16 + 3 || name.compare(0, prefix.size(), prefix) != 0) return false;
  for (size_t i = prefix.size(); i < prefix.size() + 16; ++i) {
    const unsigned char c = name[i];
    if (!std::isdigit(c) && !std::islower(c)) return false;
  }
  const std::string suffix = name.substr(name.size() - 3);
  return suffix == "_el" || suffix == "_sl";
}

}  // namespace

ShmLeftovers remove_dead_segments(const std::string& dir, double min_age_seconds) {
  ShmLeftovers out;
  std::vector<std::string> locks;
  if (DIR* d = opendir(dir.c_str())) {
    while (const dirent* e = readdir(d)) {
      if (is_segment_lock(e->d_name)) locks.emplace_back(e->d_name);
    }
    closedir(d);
  }
  const time_t now = std::time(nullptr);
  for (const std::string& name : locks) {
    const std::string lock = dir + "/" + name;
    const std::string segment = lock.substr(0, lock.size() - 3);
    struct stat ls {};
    if (stat(lock.c_str(), &ls) != 0) continue;  // removed meanwhile
    if (double(now - ls.st_mtime) < min_age_seconds) continue;
    const int fd = open(lock.c_str(), O_RDWR | O_CLOEXEC);
    if (fd < 0) {
      ++out.in_use;  // not ours to judge
      continue;
    }
    if (flock(fd, LOCK_EX | LOCK_NB) != 0) {
      ++out.in_use;  // its process lives
      close(fd);
      continue;
    }
    struct stat ss {};
    const bool had_segment = stat(segment.c_str(), &ss) == 0;
    const bool removed = had_segment && unlink(segment.c_str()) == 0;
    // The lock file goes last, while held: a second cleaner meanwhile finds it locked.
    if (removed || !had_segment) unlink(lock.c_str());
    if (removed) {
      ++out.segments;
      out.bytes += uint64_t(ss.st_blocks) * 512;
    }
    close(fd);
  }
  g_removed_segments += out.segments;
  g_removed_bytes += out.bytes;
  return out;
}

ShmLeftovers removed_by_this_process() {
  ShmLeftovers out;
  out.segments = g_removed_segments.load();
  out.bytes = g_removed_bytes.load();
  return out;
}

}  // namespace farm::dds
