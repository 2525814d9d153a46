// farm-worker: simulates a slice of the environments and streams TransitionBatches to the
// learner. It needs only the DDS domain; robot, task and policy layout come from the
// ExperimentSpec the learner publishes, so a worker can join late or restart at any time.
// This file reads the options and wires the signals; the service is WorkerApp (worker_app.cpp).
#include <signal.h>
#include <unistd.h>

#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <stdexcept>
#include <string>

#include "cli.h"
#include "config.h"
#include "dds.h"
#include "worker_app.h"

using namespace farm;

namespace {

std::atomic<bool> g_stop{false};
void on_signal(int) { g_stop = true; }

// Declares the options into o.
void add_options(CLI::App& app, WorkerOptions& o) {
  app.description(
      "Joins the learner on DDS domain D (default 0) and runs N environments on the given number of threads.\n"
      "It ignores any other experiment on the domain and ends when its experiment ends.");
  app.add_option("--envs", o.envs, "Environments to run (default: the experiment's worker.envs_per_worker)")
      ->check(CLI::Range(1, farm::kMaxEnvsPerWorker));
  app.add_option("--threads", o.threads, "Threads that step the environments")
      ->check(CLI::Range(1, farm::kMaxThreadsPerWorker));
  app.add_option("--id", o.id,
                 "The worker's name (default HOST-PID); with --security DIR (or FARM_SECURITY_DIR) it is the CN "
                 "of DIR/cert.pem by default, and another --id is refused");
  app.add_option("--experiment", o.experiment,
                 "Serve only the experiment with this experiment_id; without it, the worker serves the first "
                 "experiment it joins on the domain")
      ->check(farm::cli::non_empty("an experiment id"));
  app.add_option("--log-every", o.log_every, "Seconds between log lines")->check(CLI::Range(1, 3600));
  app.add_option("--events", o.events,
                 "Write the worker's events to FILE, one JSON object a line (appended; worker_app.h lists "
                 "the kinds)")
      ->check(farm::cli::non_empty("a file name"));
  app.add_option("--inject-nan-batch", o.inject_nan_batch, "Fault injection for tests: a NaN in batch SEQ")
      ->check(CLI::Range(0, 1 << 30));
  app.add_option("--inject-publish-delay", o.inject_publish_delay_ms,
                 "Fault injection for tests: delay each publish by MS milliseconds")
      ->check(CLI::Range(0, 60000));
  farm::dds::add_bus_options(app, o.bus);
}

// The worker's id once the options are read.
void settle_id(WorkerOptions& o) {
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
}

}  // namespace

int main(int argc, char** argv) {
  WorkerOptions opt;
  farm::cli::App app("farm-worker");
  add_options(app, opt);
  if (const int rc = farm::cli::parse(app, argc, argv); rc >= 0) return rc;
  try {
    settle_id(opt);
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
