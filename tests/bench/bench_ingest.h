// What the two modes of bench_ingest share: its options, its clock, and the batch a shipped config
// makes a worker send. The learner's side (the reader, Ingest, the algorithm's take and the update
// loop beside them) is in bench_ingest.cpp; the sender mode, the synthetic workers it starts, in
// bench_ingest_sender.cpp.
#pragma once

#include <chrono>
#include <string>
#include <vector>

#include "config.h"
#include "dds.h"
#include "task_spec.h"

namespace bench_ingest {

using Clock = std::chrono::steady_clock;
inline double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

struct Options {
  farm::dds::BusOptions bus;
  std::string config = FARM_DEFAULT_CONFIG;
  std::vector<double> rates{20, 50, 100, 200, 400, 800};
  int senders = 4;
  double seconds = 5, warmup = 1.5;
  bool with_updates = false, expect_all = false;
  std::string learner = "ingest-thread";  // one-thread, ingest-thread or both
  double tolerance = 0.03;                // taken below (1 - tolerance) x offered: not keeping up
  double max_update_drop = 0.10;          // updates/s below (1 - this) x the baseline: ingest slows training
  // Sender mode.
  bool sender = false;
  std::string experiment, id;
  double rate = 0;
};

// What a shipped config makes a worker send: the task's shape and the batch's T x N.
struct Shape {
  farm::config::ExperimentConfig cfg;
  farm::robots::TaskSpec spec;
  int steps = 0, envs = 0;
};

Shape shape_of(const std::string& config);

// One well-formed batch of the config's T steps x N envs, from sender `id`.
void fill_batch(const Shape& s, const std::string& experiment, const std::string& id, farm::msg::TransitionBatch& b);

// --sender: publishes such batches at o.rate until SIGTERM, then closes its stream; the exit code.
int run_sender(const Options& o);

}  // namespace bench_ingest
