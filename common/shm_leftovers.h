#pragma once
// Shared-memory segments that Fast DDS processes leave behind when they end without closing them
// (SIGKILL, a crash, the OOM killer): each participant makes a data segment in /dev/shm
// (fastrtps_<16 characters>, 32 MiB with deploy/fastdds_profiles.xml) and holds an exclusive
// flock on its lock file (the same name with _el) for as long as it lives. Nothing removes the
// segment of a process that died, so a host that runs and kills farms fills its /dev/shm, a
// tmpfs in memory, 32 MiB at a time.

#include <cstdint>
#include <string>

namespace farm::dds {

struct ShmLeftovers {
  int segments = 0;    // data segments removed (with their lock files)
  uint64_t bytes = 0;  // the memory they held
  int in_use = 0;      // segments whose lock a live process holds
};

// Removes from `dir` each segment whose lock file no process holds and that is at least
// `min_age_seconds` old (a lock file younger than that may belong to a process that has created it
// and is about to lock it). Segment names are random and never reused, so a live process that
// still maps a removed segment keeps its memory until it unmaps it. The ports (fastrtps_port<N>)
// are left alone: a live peer may still write into a dead process's port, and a new process must
// not listen on a port of that name (dds.cpp's participant id choice keeps away from them).
// Files the caller may not open or remove (another user's) count as in use.
ShmLeftovers remove_dead_segments(const std::string& dir = "/dev/shm", double min_age_seconds = 30.0);

// The segments and bytes remove_dead_segments has removed in this process so far, every call
// summed (in_use is 0): what a program's participants cleared before they started, for its record.
ShmLeftovers removed_by_this_process();

}  // namespace farm::dds
