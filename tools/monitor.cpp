// farm-monitor: joins the farm's DDS domain and shows a live table of the workers (from their
// WorkerStatus heartbeats) and of the learner (LearnerStats): per-worker and total throughput,
// policy versions, learning progress and batch accounting; with --prometheus it serves the same
// figures at /metrics for Prometheus to scrape. Runs on any host that reaches the domain; it only
// reads, so starting or stopping it never disturbs training.
// This file reads the options and wires the signals; the service is MonitorApp (monitor_app.cpp).
#include <signal.h>

#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <sstream>
#include <stdexcept>
#include <string>

#include "cli.h"
#include "dds.h"
#include "metrics_server.h"
#include "monitor_app.h"

using farm::MonitorApp;
using farm::MonitorOptions;

namespace {

std::atomic<bool> g_stop{false};
void on_signal(int) { g_stop = true; }

// Declares the options into o.
void add_options(CLI::App& app, MonitorOptions& o, bool& wait_given) {
  app.description(
      "Shows the farm on DDS domain D live: every worker (host, id, envs, steps/s, batches sent,\n"
      "policy version, state, age of its last heartbeat), the totals, and the learner (ingest and\n"
      "update rates, buffer fill, policy lag, losses, returns, batch accounting).");
  farm::dds::add_bus_options(app, o.bus);
  app.add_option("--experiment", o.experiment, "Only workers and learner statistics of experiment ID")
      ->check(farm::cli::non_empty("an experiment id"));
  app.add_option("--timeout", o.timeout, "A worker silent for S seconds is shown dead, out of the totals")
      ->check(farm::cli::within(0.1, 3600))
      ->capture_default_str();
  app.add_option("--interval", o.interval, "Refresh period in seconds")
      ->check(farm::cli::within(0.1, 3600))
      ->capture_default_str();
  app.add_option("--forget", o.forget, "Dead workers leave the table after S seconds")
      ->check(farm::cli::within(0, 1e7))
      ->capture_default_str();
  app.add_flag("--once", o.once,
               "Wait for one round of heartbeats and the learners' statistics, print one snapshot, exit "
               "(1: nothing found)");
  app.add_option("--wait", o.wait, "With --once: wait at most S seconds for data")
      ->check(farm::cli::within(0.1, 3600))
      ->capture_default_str()
      ->each([&wait_given](const std::string&) { wait_given = true; });
  app.add_option("--log", o.log_file, "Append one JSON line per refresh (timestamp, workers, learner, totals)")
      ->check(farm::cli::non_empty("a file name"));
  app.add_option("--prometheus", o.prometheus,
                 "ADDR:PORT: serve the same figures at http://ADDR:PORT/metrics in the Prometheus text format, "
                 "refreshed every --interval (127.0.0.1:PORT: this host only; 0.0.0.0:PORT: every interface); "
                 "series in docs/guides/monitoring.md")
      ->transform(farm::cli::checked_by(farm::MetricsServer::parse_listen_address, "ADDR:PORT"));
  app.add_flag("--quiet", o.quiet, "Print no table (with --log or --prometheus, e.g. as a service)");
}

// The combinations of options that the monitor refuses.
void check_combinations(const MonitorOptions& o, bool wait_given) {
  if (wait_given && !o.once) throw std::invalid_argument("--wait only applies with --once");
  if (o.once && !o.prometheus.empty())
    throw std::invalid_argument("--prometheus serves a live farm and cannot be combined with --once");
  if (o.quiet && (o.once || (o.log_file.empty() && o.prometheus.empty())))
    throw std::invalid_argument("--quiet only applies to a live monitor with --log or --prometheus");
}

}  // namespace

int main(int argc, char** argv) {
  MonitorOptions opt;
  bool wait_given = false;
  farm::cli::App app("farm-monitor");
  add_options(app, opt, wait_given);
  if (const int rc = farm::cli::parse(app, argc, argv); rc >= 0) return rc;
  try {
    check_combinations(opt, wait_given);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "farm-monitor: %s\n", e.what());
    return 2;
  }
  signal(SIGINT, on_signal);
  signal(SIGTERM, on_signal);
  try {
    MonitorApp m(opt, g_stop);
    return m.run();
  } catch (const std::exception& e) {
    std::fprintf(stderr, "farm-monitor: %s\n", e.what());
    return 1;
  }
}
