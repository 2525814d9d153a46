// The farm-monitor service: reads the workers' WorkerStatus heartbeats and the learner's
// LearnerStats off the bus and shows them as a table that refreshes in place (or one snapshot
// with --once), optionally appending one JSON line per refresh to a log file. It only reads, so
// starting or stopping it never disturbs training.
#pragma once

#include <atomic>
#include <cstdint>
#include <deque>
#include <fstream>
#include <map>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "dds.h"

namespace farm {

struct MonitorOptions {
  farm::dds::BusOptions bus;
  double timeout = 4.0;   // a worker silent this long is dead
  double interval = 1.0;  // refresh period
  double forget = 300.0;  // dead workers leave the table after this long
  bool once = false;
  double wait = 5.0;  // --once: longest wait for the first heartbeats
  std::string log_file;
  std::string experiment;  // empty: every experiment on the domain
};

class MonitorApp {
 public:
  // Joins the bus and opens the --log file (throws if it cannot be appended to). stop: set (by a
  // signal handler) to end run().
  MonitorApp(const MonitorOptions& o, const std::atomic<bool>& stop);

  // The live table until stopped, or with --once one snapshot; returns the process exit code
  // (--once: 1 when nothing was found).
  int run();

 private:
  struct WorkerView {
    farm::msg::WorkerStatus last;
    double first_seen = 0, seen = 0;
    // (arrival time, env_steps) of recent heartbeats: steps/s over a few seconds, so one heartbeat
    // that fell inside a pause for new weights does not read as a stopped worker.
    std::deque<std::pair<double, uint64_t>> history;
  };

  struct LearnerView {
    farm::msg::LearnerStats last;
    double seen = 0;
  };

  struct Totals {
    int live = 0, dead = 0, finished = 0;
    uint64_t envs = 0, env_steps = 0, batches = 0;
    double steps_per_second = 0;
  };

  int run_once();
  bool wanted(const std::string& experiment) const;
  void drain();
  static std::string key(const farm::msg::WorkerStatus& s);
  bool dead(const WorkerView& v, double now) const;
  std::string state(const WorkerView& v, double now) const;
  bool live(const WorkerView& v, double now) const;
  double rate(const WorkerView& v, double now) const;
  Totals totals(double now) const;
  std::vector<const WorkerView*> sorted() const;
  std::string render(double now) const;
  const LearnerView* learner() const;
  void write_log(double now);

  MonitorOptions opt_;
  const std::atomic<bool>& stop_;
  farm::dds::Bus bus_;
  farm::dds::Reader<farm::msg::WorkerStatus, farm::msg::WorkerStatusPubSubType> status_in_;
  farm::dds::Reader<farm::msg::LearnerStats, farm::msg::LearnerStatsPubSubType> stats_in_;
  double t0_;
  std::map<std::string, WorkerView> workers_;
  std::map<std::string, LearnerView> learners_;
  std::string latest_learner_;
  std::set<std::string> heard_;  // every worker session heard from, experiment filter or not
  std::ofstream log_;
};

}  // namespace farm
