// farm-worker: simulates a slice of the environments and streams TransitionBatches to the
// learner. It needs only the DDS domain; robot, task and policy layout come from the
// ExperimentSpec the learner publishes, so a worker can join late or restart at any time.
// This file reads the options and wires the signals; the service is WorkerApp (worker_app.cpp).
#include <signal.h>
#include <unistd.h>

#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <stdexcept>
#include <string>

#include "config.h"
#include "dds.h"
#include "worker_app.h"

using namespace farm;

namespace {

std::atomic<bool> g_stop{false};
void on_signal(int) { g_stop = true; }

void usage() {
  std::cout << "usage: farm-worker [--envs N] [--threads N] [--id NAME] [--domain D] [--experiment ID]\n"
               "                   [--dds-profiles FILE] [--security DIR] [--log-every SECONDS]\n"
               "                   [--inject-nan-batch SEQ] [--inject-publish-delay MS]   (fault injection for tests)\n"
               "Joins the learner on DDS domain D (default 0) and runs N environments (default:\n"
               "the experiment's worker.envs_per_worker) on the given number of threads.\n"
               "--id NAME: the worker's name (default HOST-PID); with --security DIR (or FARM_SECURITY_DIR)\n"
               "it is the CN of DIR/cert.pem by default, and another --id is refused.\n"
               "--experiment ID: serve only the experiment with this experiment_id; without it, the\n"
               "worker serves the first experiment it joins on the domain. Either way it ignores any\n"
               "other experiment on the domain and ends when its experiment ends.\n";
}

int int_flag(const std::string& name, const std::string& v, int lo, int hi) {
  try {
    size_t pos = 0;
    int x = std::stoi(v, &pos);
    if (pos == v.size() && x >= lo && x <= hi) return x;
  } catch (...) {
  }
  throw std::invalid_argument(name + " expects an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) +
                              "], got '" + v + "'");
}

WorkerOptions parse(int argc, char** argv) {
  WorkerOptions o;
  for (int i = 1; i < argc; ++i) {
    std::string a = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) throw std::invalid_argument(a + " needs a value");
      return argv[++i];
    };
    if (farm::dds::parse_bus_flag(argc, argv, i, o.bus)) continue;
    if (a == "--envs")
      o.envs = int_flag(a, value(), 1, farm::kMaxEnvsPerWorker);
    else if (a == "--threads")
      o.threads = int_flag(a, value(), 1, farm::kMaxThreadsPerWorker);
    else if (a == "--id")
      o.id = value();
    else if (a == "--experiment") {
      o.experiment = value();
      if (o.experiment.empty()) throw std::invalid_argument("--experiment needs a non-empty experiment id");
    } else if (a == "--log-every")
      o.log_every = int_flag(a, value(), 1, 3600);
    else if (a == "--inject-nan-batch")
      o.inject_nan_batch = int_flag(a, value(), 0, 1 << 30);
    else if (a == "--inject-publish-delay")
      o.inject_publish_delay_ms = int_flag(a, value(), 0, 60000);
    else if (a == "-h" || a == "--help") {
      usage();
      std::exit(0);
    } else
      throw std::invalid_argument("unknown option '" + a + "' (see --help)");
  }
  // Under DDS Security a worker's id is its certificate's name (the learner refuses batches under
  // another id), so it defaults to that name and a different --id is refused here.
  if (const std::string sec = farm::dds::security_dir_of(o.bus); !sec.empty()) {
    const std::string name = farm::dds::certificate_name(sec);
    if (o.id.empty()) o.id = name;
    if (o.id != name)
      throw std::invalid_argument("--id '" + o.id + "' is not the name in this worker's certificate ('" + name +
                                  "', CN of " + sec + "/cert.pem): with DDS Security a worker's id is its " +
                                  "certificate's name and the learner refuses batches under another; drop --id " +
                                  "or use the folder deploy/make-pki.sh made for '" + o.id + "'");
  }
  if (o.id.empty()) o.id = farm::dds::hostname() + "-" + std::to_string(getpid());
  return o;
}

}  // namespace

int main(int argc, char** argv) {
  WorkerOptions opt;
  try {
    opt = parse(argc, argv);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "farm-worker: %s\n", e.what());
    return 2;
  }
  signal(SIGINT, on_signal);
  signal(SIGTERM, on_signal);
  try {
    WorkerApp w(opt, g_stop);
    return w.run();
  } catch (const std::exception& e) {
    std::fprintf(stderr, "farm-worker: %s\n", e.what());
    return 1;
  }
}
