// The farm-monitor service: reads the workers' WorkerStatus heartbeats and the learner's
// LearnerStats off the bus and shows them as a table that refreshes in place (or one snapshot
// with --once), optionally appending one JSON line per refresh to a log file and serving the same
// figures to Prometheus at /metrics (--prometheus). Each refresh takes one MonitorSnapshot that
// the table, the log line and the metrics page are all written from. It only reads the bus, so
// starting or stopping it never disturbs training.
#pragma once

#include <atomic>
#include <cstdint>
#include <deque>
#include <fstream>
#include <map>
#include <memory>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "dds.h"
#include "metrics_server.h"
#include "monitor_snapshot.h"
#include "prometheus_text.h"

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
  std::string prometheus;  // ADDR:PORT to serve /metrics on; empty: no server
  bool quiet = false;      // print no table (a service that only logs or serves metrics)
};

class MonitorApp {
 public:
  // Starts the --prometheus server (throws if it cannot listen), joins the bus and opens the --log
  // file (throws if it cannot be appended to). stop: set (by a signal handler) to end run().
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

  int run_once();
  bool wanted(const std::string& experiment) const;
  void drain();
  static std::string key(const farm::msg::WorkerStatus& s);
  bool dead(const WorkerView& v, double now) const;
  std::string state(const WorkerView& v, double now) const;
  bool live(const WorkerView& v, double now) const;
  double rate(const WorkerView& v, double now) const;
  // What the table, the log and /metrics show at now.
  MonitorSnapshot snapshot(double now) const;
  // One refresh: the table (unless quiet), the log line, the metrics page.
  void show(double now);
  void write_log(const MonitorSnapshot& s);

  MonitorOptions opt_;
  const std::atomic<bool>& stop_;
  std::unique_ptr<MetricsServer> metrics_;  // before the bus: a bad address fails before joining
  PrometheusMetrics prometheus_;            // what metrics_ serves, brought to each snapshot
  farm::dds::Bus bus_;
  farm::dds::Reader<farm::msg::WorkerStatus, farm::msg::WorkerStatusPubSubType> status_in_;
  farm::dds::Reader<farm::msg::LearnerStats, farm::msg::LearnerStatsPubSubType> stats_in_;
  double t0_;
  std::map<std::string, WorkerView> workers_;
  std::map<std::string, LearnerView> learners_;
  std::string latest_learner_;
  std::set<std::string> heard_;        // every worker session heard from, experiment filter or not
  std::set<std::string> stats_heard_;  // every learner (experiment id) heard from, filter or not
  // Each table above holds at most kMaxEntries; each text from a heartbeat at most kMaxTextBytes.
  static constexpr size_t kMaxEntries = 4096, kMaxTextBytes = 256;
  static constexpr size_t kMaxStats = 256;  // fields of one learner's statistics record kept
  // Heartbeats refused under security because their worker id is not their writer's certificate name.
  uint64_t refused_for_name_ = 0;
  static constexpr uint64_t kMaxRefusalNotes = 10;
  std::ofstream log_;
};

}  // namespace farm
