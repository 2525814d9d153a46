// What farm-monitor knows of the farm at one instant, as plain values: every worker's row, the
// totals over the live ones and the learners' statistics. The live table, the --once snapshot, the
// JSON log line and the Prometheus /metrics page are all written from one MonitorSnapshot, so the
// figures they show for one instant are the same figures.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "learner_stats_fields.h"

namespace farm {

struct WorkerRow {
  std::string id, host, experiment, last_error;
  uint64_t session = 0;
  uint32_t envs = 0, threads = 0;
  double steps_per_second = 0;  // the monitor's rate over recent heartbeats; 0 when dead
  uint64_t env_steps = 0, batches_sent = 0, policy_version = 0;
  std::string state;  // the worker's own state, or "dead" when silent longer than the timeout
  bool alive = false;
  double age_s = 0;  // seconds since its last heartbeat
};

struct WorkerTotals {
  int live = 0, dead = 0, finished = 0;  // live: alive and not finished; only live workers are summed
  uint64_t envs = 0, env_steps = 0, batches = 0;
  double steps_per_second = 0;
};

// One learner's latest LearnerStats (field for field) and how long ago it arrived.
struct LearnerRow {
  std::string experiment;
  double age_s = 0;
  // LearnerStats' typed fields under their members' names (elapsed_seconds, env_steps, ...,
  // workers); a loss or return is NaN until the learner has one.
#define FARM_ROW_MEMBER(name, member, type) type member = 0;
  FARM_LEARNER_STATS_FIELDS(FARM_ROW_MEMBER)
#undef FARM_ROW_MEMBER
  // Every field of the learner's statistics record (LearnerStats' `stats`): name, unit, value.
  struct Stat {
    std::string name, unit;
    double value = 0;  // NaN: none yet
  };
  std::vector<Stat> stats;
};

struct MonitorSnapshot {
  int64_t unix_ms = 0;             // wall clock of the snapshot, milliseconds since 1970
  double elapsed_s = 0;            // since the monitor started
  int domain = 0;                  // DDS domain
  std::string experiment;          // the --experiment filter; empty: every experiment
  double timeout = 0;              // a worker silent this long is dead
  std::vector<WorkerRow> workers;  // sorted by host, then worker id
  WorkerTotals totals;
  std::vector<LearnerRow> learners;  // one per experiment heard, sorted by experiment id
  int latest_learner = -1;           // index into learners of the one heard last (the table's); -1: none
};

// The table farm-monitor prints (live, or once with --once).
std::string render_table(const MonitorSnapshot& s);

// The --log line: one JSON object (time, workers, the latest learner, totals) and a newline.
std::string render_json_line(const MonitorSnapshot& s);

}  // namespace farm
