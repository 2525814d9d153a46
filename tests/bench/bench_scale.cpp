// Farm scaling: total env steps/s arriving at a learner from 1, 2, 4, ... real farm-worker
// processes, as a fraction of (1 worker's rate x workers). This process plays the learner's
// transport side: it publishes the ExperimentSpec and policy weights, and passes every batch
// through the learner's Ingest (checks, accounting, flattening), but does not train, so the
// figure is the farm's supply of experience, not a learner's appetite.
//
//   bench_scale [--workers 1,2,4,8,15] [--envs E] [--steps T] [--seconds S] [--warmup S]
//               [--worker-bin PATH] [--log-dir DIR] [--domain D] [--dds-profiles FILE]
//
// The workers: --worker-bin, else farm-worker next to this program (a copied or installed
// folder), else ../worker/farm-worker (the build tree), else the path it was built at.
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <random>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "bench_options.h"
#include "dds.h"
#include "ingest.h"
#include "meter.h"
#include "mlp.h"
#include "paths.h"

namespace {

using Clock = std::chrono::steady_clock;

struct Options {
  farm::dds::BusOptions bus;
  std::vector<int> workers{1, 2, 4, 8, 15};
  int envs = 16, steps = 32;
  double seconds = 5, warmup = 3;
  std::string worker_bin;  // --worker-bin; else next to this program, then the build tree's
  std::string log_dir = "/tmp/bench_scale";
};

// Declares the options into o.
void add_options(CLI::App& app, Options& o) {
  app.description(
      "Farm scaling: total env steps/s arriving at a learner from 1, 2, 4, ... real farm-worker "
      "processes, as a fraction of (1 worker's rate x workers).");
  farm::dds::add_bus_options(app, o.bus);
  bench::add_list(app, "--workers", o.workers, "Worker counts to measure")->check(CLI::Range(1, 100000));
  app.add_option("--envs", o.envs, "Environments per worker")->check(CLI::Range(1, 100000))->capture_default_str();
  app.add_option("--steps", o.steps, "Steps per batch")->check(CLI::Range(1, 100000))->capture_default_str();
  bench::add_seconds(app, o.seconds, "Seconds measured per worker count");
  app.add_option("--warmup", o.warmup, "Seconds of warm-up before each measurement")
      ->check(farm::cli::within(0, 1e9))
      ->capture_default_str();
  app.add_option("--worker-bin", o.worker_bin,
                 "The farm-worker program (default: next to this program, then the build tree's)");
  app.add_option("--log-dir", o.log_dir, "Folder of the workers' logs")->capture_default_str();
}

pid_t spawn(const std::vector<std::string>& argv, const std::string& log) {
  std::fflush(stdout);  // or the child would write out this process's buffered lines again
  const pid_t pid = fork();
  if (pid == 0) {
    if (!freopen(log.c_str(), "w", stdout)) _exit(126);
    dup2(fileno(stdout), 2);
    std::vector<char*> args;
    for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    execv(args[0], args.data());
    std::fprintf(stderr, "cannot start %s: %s\n", args[0], std::strerror(errno));
    _exit(127);
  }
  return pid;
}

class Sink {
 public:
  explicit Sink(const Options& o)
      : o_(o),
        bus_(o.bus, "bench_scale"),
        spec_out_(bus_, farm::dds::kSpecTopic, "latest_writer"),
        weights_out_(bus_, farm::dds::kWeightsTopic, "latest_writer"),
        batches_in_(bus_, farm::dds::kBatchTopic, "batch_reader") {}

  // Env steps/s over the measured window with n workers, or a negative value on failure.
  double run(int n) {
    const std::string id = "bench_scale_" + std::to_string(n) + "_" + std::to_string(getpid());
    farm::Ingest ingest(id, kObs, kAct, kMetrics);
    publish(id, false);
    std::vector<pid_t> pids;
    for (int k = 0; k < n; ++k) {
      pids.push_back(spawn({o_.worker_bin, "--envs", std::to_string(o_.envs), "--threads", "1", "--id",
                            "w" + std::to_string(k), "--domain", std::to_string(o_.bus.domain), "--log-every", "1"},
                           o_.log_dir + "/" + id + "_w" + std::to_string(k) + ".log"));
    }
    farm::Transitions tr;
    std::vector<farm::FinishedEpisode> eps;
    farm::msg::TransitionBatch b;
    const auto t_start = Clock::now();
    auto since = [](Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); };
    bool measuring = false;
    uint64_t steps0 = 0;
    Clock::time_point t0{};
    double rate = -1;
    uint64_t refused = 0;
    bool failed = false;
    for (;;) {
      batches_in_.wait(0.02);
      while (batches_in_.take(b)) {
        tr.clear();
        eps.clear();
        if (!ingest.accept(b, 0, farm::now_seconds(), tr, eps).empty()) ++refused;
      }
      const auto& w = ingest.workers();
      int active = 0;
      for (const auto& [key, acc] : w) active += acc.received >= 2;
      if (!measuring) {
        for (size_t k = 0; k < pids.size(); ++k) {
          int status = 0;
          if (pids[k] > 0 && waitpid(pids[k], &status, WNOHANG) == pids[k]) {
            std::fprintf(stderr, "worker w%zu (%s) exited with %s %d before delivering (log %s)\n", k,
                         o_.worker_bin.c_str(), WIFEXITED(status) ? "code" : "signal",
                         WIFEXITED(status) ? WEXITSTATUS(status) : WTERMSIG(status),
                         (o_.log_dir + "/" + id + "_w" + std::to_string(k) + ".log").c_str());
            pids[k] = -1;
            failed = true;
          }
        }
        if (failed) break;
        if (active == n && since(t_start) > o_.warmup) {
          measuring = true;
          steps0 = ingest.counters().env_steps;
          t0 = Clock::now();
        } else if (since(t_start) > 60) {
          std::fprintf(stderr, "only %d of %d workers delivered within 60 s (logs in %s)\n", active, n,
                       o_.log_dir.c_str());
          break;
        }
      } else if (since(t0) >= o_.seconds) {
        rate = double(ingest.counters().env_steps - steps0) / since(t0);
        break;
      }
    }
    for (pid_t p : pids)
      if (p > 0) kill(p, SIGTERM);
    const auto t_stop = Clock::now();
    // Drain the end-of-stream batches so the accounting below covers every batch sent.
    for (pid_t p : pids) {
      if (p <= 0) continue;
      int status = 0;
      while (waitpid(p, &status, WNOHANG) != p) {
        batches_in_.wait(0.02);
        while (batches_in_.take(b)) {
          tr.clear();
          eps.clear();
          if (!ingest.accept(b, 0, farm::now_seconds(), tr, eps).empty()) ++refused;
        }
        if (since(t_stop) > 30) {
          kill(p, SIGKILL);
          waitpid(p, &status, 0);
          break;
        }
      }
    }
    publish(id, true);
    const auto& c = ingest.counters();
    lost_ = c.lost;
    invalid_ = refused;  // invalid, duplicate or foreign: any batch Ingest turned away
    duplicate_ = c.duplicate;
    return rate;
  }
  uint64_t lost() const { return lost_; }
  uint64_t invalid() const { return invalid_; }
  uint64_t duplicate() const { return duplicate_; }

 private:
  static constexpr int kObs = 3, kAct = 1, kMetrics = 1;  // the pendulum (its metric: upright_fraction)

  void publish(const std::string& id, bool finished) {
    farm::msg::ExperimentSpec s;
    s.experiment_id(id);
    s.config_text("experiment_id: \"" + id + "\"\ntask { name: \"pendulum\" }\n");
    s.task_name("pendulum");
    s.obs_dim(kObs);
    s.act_dim(kAct);
    s.steps_per_batch(o_.steps);
    // Never throttled by policy lag: the sink publishes one policy and never trains.
    s.max_batches_per_version(1u << 30);
    s.seed(1);
    s.learner_session(1);
    s.finished(finished);
    spec_out_.write(s);
    if (finished) return;
    farm::PolicyParams p;
    p.layout = {{kObs, 64, 64, 2 * kAct}, farm::Activation::kRelu};
    p.params.resize(p.layout.num_params());
    std::mt19937_64 rng(1);
    std::normal_distribution<float> normal(0.f, 0.2f);
    for (auto& v : p.params) v = normal(rng);
    farm::msg::PolicyWeights w;
    farm::dds::to_wire(p, id, w);
    weights_out_.write(w);
  }

  const Options& o_;
  farm::dds::Bus bus_;
  farm::dds::Writer<farm::msg::ExperimentSpec, farm::msg::ExperimentSpecPubSubType> spec_out_;
  farm::dds::Writer<farm::msg::PolicyWeights, farm::msg::PolicyWeightsPubSubType> weights_out_;
  farm::dds::Reader<farm::msg::TransitionBatch, farm::msg::TransitionBatchPubSubType> batches_in_;
  uint64_t lost_ = 0, invalid_ = 0, duplicate_ = 0;
};

}  // namespace

int main(int argc, char** argv) {
  Options o;
  farm::cli::App app("bench_scale");
  add_options(app, o);
  if (const int rc = farm::cli::parse(app, argc, argv); rc >= 0) return rc;
  try {
    o.worker_bin =
        farm::find_companion("farm-worker", o.worker_bin, "../worker/farm-worker", FARM_WORKER_BIN, "--worker-bin");
    std::filesystem::create_directories(o.log_dir);
    // The workers read the same profiles through the standard variable.
    if (!o.bus.profiles_file.empty()) setenv("FASTRTPS_DEFAULT_PROFILES_FILE", o.bus.profiles_file.c_str(), 1);
    Sink sink(o);
    std::printf("bench_scale: workers %s\n", o.worker_bin.c_str());
    std::printf(
        "bench_scale: pendulum, %d envs x %d steps per batch per worker, 1 thread each, "
        "%.0f s measured after %.0f s warm-up; %u cores\n",
        o.envs, o.steps, o.seconds, o.warmup, std::thread::hardware_concurrency());
    std::printf("%8s %14s %16s %14s %7s %6s %8s\n", "workers", "env steps/s", "per worker", "limit", "ratio", "lost",
                "refused");
    double one = 0;
    bool ok = true;
    for (int n : o.workers) {
      const double r = sink.run(n);
      if (r < 0) {
        ok = false;
        continue;
      }
      if (one == 0) one = n == 1 ? r : 0;
      const double limit = one * n;
      std::printf("%8d %14.0f %16.0f %14.0f %7.3f %6llu %8llu\n", n, r, r / n, limit, limit > 0 ? r / limit : 0.0,
                  (unsigned long long)sink.lost(), (unsigned long long)sink.invalid());
      std::fflush(stdout);
      ok = ok && sink.lost() == 0 && sink.invalid() == 0;
    }
    return ok ? 0 : 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_scale: %s\n", e.what());
    return 2;
  }
}
