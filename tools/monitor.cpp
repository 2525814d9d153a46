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

#include "dds.h"
#include "metrics_server.h"
#include "monitor_app.h"

using farm::MonitorApp;
using farm::MonitorOptions;

namespace {

std::atomic<bool> g_stop{false};
void on_signal(int) { g_stop = true; }

void usage() {
  std::cout << "usage: farm-monitor [--domain D] [--dds-profiles FILE] [--security DIR]\n"
               "                    [--experiment ID] [--timeout S] [--interval S] [--forget S]\n"
               "                    [--once [--wait S]] [--log FILE] [--prometheus ADDR:PORT] [--quiet]\n"
               "Shows the farm on DDS domain D live: every worker (host, id, envs, steps/s, batches sent,\n"
               "policy version, state, age of its last heartbeat), the totals, and the learner (ingest and\n"
               "update rates, buffer fill, policy lag, losses, returns, batch accounting).\n"
               "  --experiment ID  only workers and learner statistics of experiment ID\n"
               "  --timeout S      a worker silent for S seconds is shown dead, out of the totals (default 4)\n"
               "  --interval S     refresh period (default 1)\n"
               "  --forget S       dead workers leave the table after S seconds (default 300)\n"
               "  --once           wait for one round of heartbeats and the learners' statistics, print one\n"
               "                   snapshot, exit (1: nothing found)\n"
               "  --wait S         with --once: wait at most S seconds for data (default 5)\n"
               "  --log FILE       append one JSON line per refresh (timestamp, workers, learner, totals)\n"
               "  --prometheus ADDR:PORT  serve the same figures at http://ADDR:PORT/metrics in the Prometheus\n"
               "                   text format, refreshed every --interval (127.0.0.1:PORT: this host only;\n"
               "                   0.0.0.0:PORT: every interface); series in docs/MONITORING.md\n"
               "  --quiet          print no table (with --log or --prometheus, e.g. as a service)\n";
}

double seconds_flag(const std::string& name, const std::string& v, double lo, double hi) {
  try {
    size_t pos = 0;
    double x = std::stod(v, &pos);
    if (pos == v.size() && std::isfinite(x) && x >= lo && x <= hi) return x;
  } catch (...) {
  }
  std::ostringstream o;
  o << name << " expects a number of seconds in [" << lo << ", " << hi << "], got '" << v << "'";
  throw std::invalid_argument(o.str());
}

MonitorOptions parse(int argc, char** argv) {
  MonitorOptions o;
  bool wait_given = false;
  for (int i = 1; i < argc; ++i) {
    std::string a = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) throw std::invalid_argument(a + " needs a value");
      return argv[++i];
    };
    if (farm::dds::parse_bus_flag(argc, argv, i, o.bus)) continue;
    if (a == "--timeout")
      o.timeout = seconds_flag(a, value(), 0.1, 3600);
    else if (a == "--interval")
      o.interval = seconds_flag(a, value(), 0.1, 3600);
    else if (a == "--forget")
      o.forget = seconds_flag(a, value(), 0, 1e7);
    else if (a == "--once")
      o.once = true;
    else if (a == "--wait") {
      o.wait = seconds_flag(a, value(), 0.1, 3600);
      wait_given = true;
    } else if (a == "--log") {
      o.log_file = value();
      if (o.log_file.empty()) throw std::invalid_argument("--log needs a file name");
    } else if (a == "--prometheus") {
      o.prometheus = farm::MetricsServer::parse_listen_address(value());
    } else if (a == "--quiet") {
      o.quiet = true;
    } else if (a == "--experiment") {
      o.experiment = value();
      if (o.experiment.empty()) throw std::invalid_argument("--experiment needs an experiment id");
    } else if (a == "-h" || a == "--help") {
      usage();
      std::exit(0);
    } else
      throw std::invalid_argument("unknown option '" + a + "' (see --help)");
  }
  if (wait_given && !o.once) throw std::invalid_argument("--wait only applies with --once");
  if (o.once && !o.prometheus.empty())
    throw std::invalid_argument("--prometheus serves a live farm and cannot be combined with --once");
  if (o.quiet && (o.once || (o.log_file.empty() && o.prometheus.empty())))
    throw std::invalid_argument("--quiet only applies to a live monitor with --log or --prometheus");
  return o;
}

}  // namespace

int main(int argc, char** argv) {
  MonitorOptions opt;
  try {
    opt = parse(argc, argv);
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
