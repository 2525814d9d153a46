// The ingest ceiling of one learner: batches/s and MB/s that the learner's receive path takes before
// it falls behind what is offered, or before it slows a SAC update loop running beside it. This
// process plays the learner's receive side: a batch reader with the learner's QoS and size bound,
// Ingest (checks, accounting, flattening), then the algorithm's own take (the replay buffer with
// n-step folding for SAC/DQN, the rollout storage for PPO). Its senders are copies of this program
// in --sender mode on the same host, each publishing well-formed TransitionBatch samples of the
// config's task and batch shape at a fixed rate. The offered rate goes up step by step; each step
// prints offered and taken batches/s, MB/s, lost and invalid, and with --with-updates the update
// rate of a real SAC (1 compute thread) in this process, next to its rate with no ingest, measured
// just before each step in the same run. The ceiling is the first step where taken < offered (by
// more than --tolerance) or the update rate drops by more than --max-update-drop; the run stops
// after two steps past it in a row. --learner both runs each step twice, with the learner's loop
// taking the batches itself (one-thread, the learner before its ingest thread) and with the
// learner's IngestThread taking them (ingest-thread), so the two stand side by side in one run.
//
//   bench_ingest [--config FILE] [--rates R1,R2,...] [--senders K] [--seconds S] [--warmup S]
//                [--with-updates] [--learner one-thread|ingest-thread|both] [--tolerance F]
//                [--max-update-drop F] [--expect-all]
//                [--domain D] [--dds-profiles FILE]
//   bench_ingest --sender --config FILE --experiment ID --id NAME --rate R [--domain D] [--dds-profiles FILE]
//
// --rates are total offered batches/s, shared evenly by the K senders. --expect-all: exit 1 unless
// every step took what was offered with nothing lost or invalid (the ctest smoke test). This file
// is the options and the learner's side; the sender mode is bench_ingest_sender.cpp.
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <functional>
#include <memory>
#include <mutex>
#include <random>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "bench_ingest.h"
#include "bench_options.h"
#include "compute.h"
#include "config.h"
#include "dds.h"
#include "events.h"
#include "ingest.h"
#include "ingest_thread.h"
#include "meter.h"
#include "registry.h"
#include "replay_buffer.h"
#include "rollout_storage.h"
#include "sac.h"
#include "task_spec.h"

namespace bench_ingest {
namespace {

// Declares the options into o.
void add_options(CLI::App& app, Options& o) {
  app.description("The ingest ceiling of one learner: batches/s and MB/s its receive path takes.");
  farm::dds::add_bus_options(app, o.bus);
  app.add_option("--config", o.config, "The experiment whose task and batch shape the senders send")
      ->capture_default_str();
  bench::add_list(app, "--rates", o.rates, "Total offered batches/s of each step, shared by the senders")
      ->check(farm::cli::above(0, 100000));
  app.add_option("--senders", o.senders, "Sender processes")->check(CLI::Range(1, 64))->capture_default_str();
  bench::add_seconds(app, o.seconds, "Seconds measured per step")->check(farm::cli::above(0, 600));
  app.add_option("--warmup", o.warmup, "Seconds of warm-up before each step")
      ->check(farm::cli::above(0, 60))
      ->capture_default_str();
  app.add_option("--tolerance", o.tolerance, "Taken below (1 - F) x offered: not keeping up (a fraction below 1)")
      ->check(farm::cli::positive())
      ->capture_default_str();
  app.add_option("--max-update-drop", o.max_update_drop,
                 "Updates/s below (1 - F) x the baseline: ingest slows training (a fraction below 1)")
      ->check(farm::cli::positive())
      ->capture_default_str();
  app.add_flag("--with-updates", o.with_updates, "Run a real SAC update loop beside ingest and measure its rate");
  app.add_option("--learner", o.learner,
                 "How the learner's loop meets the batches: one-thread (it takes them off the reader itself, as "
                 "the learner did before its ingest thread), ingest-thread (the learner's IngestThread takes them), "
                 "or both, one after the other at each step")
      ->check(CLI::IsMember({"one-thread", "ingest-thread", "both"}))
      ->capture_default_str();
  app.add_flag("--expect-all", o.expect_all,
               "Exit 1 unless every step took what was offered with nothing lost or invalid");
  app.add_flag("--sender", o.sender, "Sender mode: publish batches at --rate (needs --experiment, --id, --rate)");
  app.add_option("--experiment", o.experiment, "Sender mode: the experiment id of its batches");
  app.add_option("--id", o.id, "Sender mode: the worker id of its batches");
  app.add_option("--rate", o.rate, "Sender mode: batches/s")->check(farm::cli::positive());
}

// The combinations of options that bench_ingest refuses.
void check_combinations(const Options& o) {
  if (o.tolerance >= 1 || o.max_update_drop >= 1)
    throw std::invalid_argument("--tolerance and --max-update-drop are fractions below 1");
  if (o.sender && (o.experiment.empty() || o.id.empty() || o.rate <= 0))
    throw std::invalid_argument("--sender needs --experiment, --id and --rate");
}

// ---- the learner's side --------------------------------------------------------------------------

pid_t spawn(const std::vector<std::string>& argv, const std::string& log) {
  std::fflush(stdout);
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

// This program, for the senders: /proc/self/exe names this process's own image even when the file
// was rebuilt or removed while it runs.
std::string self_exe() {
  if (access("/proc/self/exe", X_OK) != 0)
    throw std::runtime_error(std::string("cannot run /proc/self/exe for the senders: ") + std::strerror(errno));
  return "/proc/self/exe";
}

// A real SAC: the task's SAC settings (defaults for a PPO task), a replay buffer filled with random
// rows, 1 compute thread; step() is one update.
class Updater {
 public:
  explicit Updater(const Shape& s)
      : cfg_(s.cfg.algorithm() == "sac" ? s.cfg.sac() : farm::config::SacConfig()),
        sac_(cfg_, s.spec.obs_dim, s.spec.act_dim, 1),
        buf_(100000, s.spec.obs_dim, s.spec.act_dim) {
    std::mt19937_64 rng(2);
    std::normal_distribution<float> g;
    const int64_t n = 50000, o = s.spec.obs_dim, a = s.spec.act_dim;
    std::vector<float> obs(n * o), act(n * a), rew(n), next(n * o);
    std::vector<uint8_t> term(n, 0);
    for (auto* v : {&obs, &rew, &next})
      for (float& x : *v) x = g(rng);
    for (float& x : act) x = std::tanh(g(rng));
    buf_.add_n(n, obs.data(), act.data(), rew.data(), term.data(), next.data());
  }
  void step() {
    sac_.update(buf_.sample(cfg_.batch_size(), rng_));
    updates_.fetch_add(1, std::memory_order_relaxed);
  }
  uint64_t updates() const { return updates_.load(std::memory_order_relaxed); }
  std::string describe() const {
    std::string h;
    for (int x : farm::sac_hidden(cfg_)) h += (h.empty() ? "" : "-") + std::to_string(x);
    return "SAC " + h + ", batch " + std::to_string(cfg_.batch_size());
  }
  // Its rate alone, over `seconds` on a thread of its own (the machine's load may change between
  // steps, so it is measured before each).
  double alone(double seconds) {
    std::atomic<bool> stop{false};
    std::thread t([&] {
      while (!stop) step();
    });
    const uint64_t u0 = updates();
    const auto t0 = Clock::now();
    std::this_thread::sleep_for(std::chrono::duration<double>(seconds));
    const double rate = double(updates() - u0) / since(t0);
    stop = true;
    t.join();
    return rate;
  }

 private:
  farm::config::SacConfig cfg_;
  farm::Sac sac_;
  farm::ReplayBuffer buf_;
  std::mt19937_64 rng_{3};
  std::atomic<uint64_t> updates_{0};
};

// The algorithm's own insert of an accepted batch: an off-policy algorithm's from the registry
// (n-step fold, replay buffer), or else PPO's rollout storage, emptied at each fit's worth of steps
// as a fit would.
class Path {
 public:
  explicit Path(const Shape& s) : s_(s), storage_(s.spec.obs_dim, s.spec.act_dim) {
    if (!farm::find_algorithm(s.cfg.algorithm()).on_policy) algo_ = farm::make_algorithm(s.cfg, s.spec);
  }
  std::string describe() const {
    return algo_ ? "replay buffer (" + s_.cfg.algorithm() + "'s insert: n-step fold, replay)"
                 : "rollout storage (PPO, emptied every " + std::to_string(s_.cfg.ppo().steps_per_fit()) + " steps)";
  }
  void take(const farm::Batch& b) {
    if (b.rows->n == 0) return;
    if (algo_) {
      algo_->insert(b);
      return;
    }
    const farm::Transitions& r = *b.rows;
    storage_.add(b.num_steps, b.num_envs, r.obs.data(), r.actions.data(), r.rewards.data(), r.terminated.data(),
                 b.truncated, b.log_probs, r.next_obs.data(), b.policy_version);
    if (storage_.steps() >= s_.cfg.ppo().steps_per_fit()) storage_.clear();
  }

 private:
  const Shape& s_;
  std::unique_ptr<farm::Algorithm> algo_;
  farm::RolloutStorage storage_;
};

// How the learner's loop meets the batches:
//   one-thread     the learner before ingest had a thread of its own: one loop takes up to 256
//                  batches off the reader (checks, accounts, the algorithm's take), then updates
//   ingest-thread  the learner's IngestThread takes, checks and accounts on its own thread; the
//                  loop pops up to 256 accepted batches into the algorithm, then updates
enum class LearnerShape { kOneThread, kIngestThread };
const char* shape_name(LearnerShape l) { return l == LearnerShape::kOneThread ? "one-thread" : "ingest-thread"; }
constexpr size_t kDrainMax = 256;  // the learner loop's batches per pass

// One step's receive side and learner loop, running from construction to destruction.
class Intake {
 public:
  Intake(farm::dds::Bus& bus, const Shape& s, LearnerShape shape, const std::string& id, Path& path, Updater* upd)
      : path_(path), upd_(upd) {
    farm::Ingest ingest(id, s.spec.obs_dim, s.spec.act_dim, int(s.spec.metric_names.size()));
    ingest.set_num_actions(s.spec.num_actions);
    const uint32_t bound = uint32_t(
        farm::Ingest::max_batch_bytes(s.spec.obs_dim, s.spec.act_dim, int(s.spec.metric_names.size()), s.steps));
    if (shape == LearnerShape::kOneThread) {
      ingest_ = std::make_unique<farm::Ingest>(std::move(ingest));
      reader_ = std::make_unique<Reader>(bus, farm::dds::kBatchTopic, "batch_reader", bound);
    } else {
      thread_in_ = std::make_unique<farm::IngestThread>(
          bus, std::move(ingest), bound, size_t(s.cfg.ingest_queue_mib() * 1024 * 1024),
          [](const std::string& line) { std::fprintf(stderr, "bench_ingest: %s\n", line.c_str()); }, events_);
      thread_in_->start(0);  // the senders write version 0, as the one-thread loop takes them
    }
    loop_ = std::thread([this] { loop(); });
  }
  ~Intake() {
    stop_ = true;
    loop_.join();
  }
  // f on the accounts, with the loop held.
  void with_ingest(const std::function<void(const farm::Ingest&)>& f) {
    if (thread_in_) {
      thread_in_->with_ingest([&](farm::Ingest& in) { f(in); });
      return;
    }
    std::lock_guard<std::mutex> lk(mu_);
    ingest_->count_refused_samples(reader_->refused());
    f(*ingest_);
  }
  uint64_t ok() {
    uint64_t n = 0;
    with_ingest([&](const farm::Ingest& in) { n = in.counters().ok; });
    return n;
  }

 private:
  using Reader = farm::dds::Reader<farm::msg::TransitionBatch, farm::msg::TransitionBatchPubSubType>;

  void loop() {
    farm::msg::TransitionBatch m;
    farm::Transitions rows;
    std::vector<farm::FinishedEpisode> eps;
    while (!stop_) {
      size_t n = 0;
      if (thread_in_) {
        n = thread_in_->pop(kDrainMax, [&](farm::AcceptedBatch& a) { path_.take(a.view()); });
      } else {
        while (n < kDrainMax && reader_->take(m)) {
          ++n;
          rows.clear();
          eps.clear();
          std::lock_guard<std::mutex> lk(mu_);
          if (!ingest_->accept(m, 0, farm::now_seconds(), rows, eps).empty()) continue;
          path_.take(farm::Batch{m.worker_id(), m.policy_version(), int(m.num_steps()), int(m.num_envs()),
                                 m.truncated().data(), m.log_probs().data(), &rows, &eps});
        }
      }
      if (upd_)
        upd_->step();
      else if (n == 0 && thread_in_)
        thread_in_->wait(0.01);
      else if (n == 0)
        reader_->wait(0.01);
    }
  }

  Path& path_;
  Updater* upd_;
  farm::EventLog events_;                 // not opened: the learner's events are not this benchmark's
  std::unique_ptr<farm::Ingest> ingest_;  // one-thread: guarded by mu_
  std::unique_ptr<Reader> reader_;        // one-thread
  std::unique_ptr<farm::IngestThread> thread_in_;
  std::mutex mu_;
  std::atomic<bool> stop_{false};
  std::thread loop_;
};

struct Step {
  double offered = 0, taken = 0, mbps = 0, updates = -1;
  uint64_t lost = 0, invalid = 0, duplicate = 0;
  bool failed = false;
};

class Learner {
 public:
  Learner(const Options& o, const Shape& s, double batch_mb)
      : o_(o), s_(s), batch_mb_(batch_mb), bus_(o.bus, "bench_ingest"), path_(s) {}

  const Path& path() const { return path_; }

  Step run(int step, double rate, LearnerShape shape, Updater* updates) {
    Step r;
    r.offered = rate;
    const std::string id =
        "bench_ingest_" + std::to_string(getpid()) + "_" + std::to_string(step) + "_" + shape_name(shape);
    auto intake = std::make_unique<Intake>(bus_, s_, shape, id, path_, updates);
    std::vector<pid_t> pids;
    const std::string exe = self_exe();
    for (int k = 0; k < o_.senders; ++k) {
      std::vector<std::string> argv{exe,
                                    "--sender",
                                    "--config",
                                    o_.config,
                                    "--experiment",
                                    id,
                                    "--id",
                                    "s" + std::to_string(k),
                                    "--rate",
                                    std::to_string(rate / o_.senders),
                                    "--domain",
                                    std::to_string(o_.bus.domain)};
      if (!o_.bus.profiles_file.empty()) argv.insert(argv.end(), {"--dds-profiles", o_.bus.profiles_file});
      pids.push_back(spawn(argv, "/tmp/" + id + "_s" + std::to_string(k) + ".log"));
    }
    const auto t_start = Clock::now();
    for (;;) {
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
      int active = 0;
      intake->with_ingest([&](const farm::Ingest& in) {
        for (const auto& [key, acc] : in.workers()) active += acc.received >= 1;
      });
      if (active == o_.senders) break;
      if (since(t_start) > 60) {
        std::fprintf(stderr, "only %d of %d senders delivered within 60 s (logs /tmp/%s_s*.log)\n", active, o_.senders,
                     id.c_str());
        r.failed = true;
        break;
      }
    }
    if (!r.failed) {
      std::this_thread::sleep_for(std::chrono::duration<double>(o_.warmup));
      const uint64_t ok0 = intake->ok(), upd0 = updates ? updates->updates() : 0;
      const auto t0 = Clock::now();
      std::this_thread::sleep_for(std::chrono::duration<double>(o_.seconds));
      const double dt = since(t0);
      r.taken = double(intake->ok() - ok0) / dt;
      r.mbps = r.taken * batch_mb_;
      if (updates) r.updates = double(updates->updates() - upd0) / dt;
    }
    for (pid_t p : pids) kill(p, SIGTERM);
    // Every stream's end is taken, so lost counts every number a sender used and never delivered.
    const auto t_stop = Clock::now();
    for (;;) {
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
      bool all_ended = false;
      intake->with_ingest([&](const farm::Ingest& in) {
        all_ended = int(in.workers().size()) == o_.senders;
        for (const auto& [key, acc] : in.workers()) all_ended = all_ended && acc.ended;
      });
      if (all_ended || since(t_stop) > 20) {
        if (!all_ended) {
          std::fprintf(stderr, "step %d: not every sender closed its stream within 20 s\n", step);
          r.failed = true;
        }
        break;
      }
    }
    for (pid_t p : pids) {
      int status = 0;
      const auto t = Clock::now();
      while (waitpid(p, &status, WNOHANG) != p) {
        if (since(t) > 10) {
          kill(p, SIGKILL);
          waitpid(p, &status, 0);
          break;
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
      }
      if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) {
        std::fprintf(stderr, "step %d: a sender ended with status %d (logs /tmp/%s_s*.log)\n", step, status,
                     id.c_str());
        r.failed = true;
      }
    }
    // The senders' logs are kept only when a step failed.
    for (int k = 0; k < o_.senders && !r.failed; ++k)
      std::remove(("/tmp/" + id + "_s" + std::to_string(k) + ".log").c_str());
    intake->with_ingest([&](const farm::Ingest& in) {
      const auto& c = in.counters();
      r.lost = c.lost;
      r.invalid = c.invalid;
      r.duplicate = c.duplicate;
    });
    return r;
  }

 private:
  const Options& o_;
  const Shape& s_;
  double batch_mb_;
  farm::dds::Bus bus_;
  Path path_;
};

double load_average() {
  std::ifstream in("/proc/loadavg");
  double l = -1;
  in >> l;
  return l;
}

int run_learner(const Options& o) {
  const Shape s = shape_of(o.config);
  farm::configure_compute(1);
  std::printf("bench_ingest: nproc %u, 1-minute load average %.2f at start\n", std::thread::hardware_concurrency(),
              load_average());
  farm::msg::TransitionBatch probe;
  fill_batch(s, "x", "s0", probe);
  farm::msg::TransitionBatchPubSubType type;
  const double batch_mb = type.getSerializedSizeProvider(&probe)() / 1e6;
  std::printf("bench_ingest: %s (%s), obs %d act %d, batch %d steps x %d envs = %d transitions, %.4f MB serialized\n",
              s.spec.name.c_str(), o.config.c_str(), s.spec.obs_dim, s.spec.act_dim, s.steps, s.envs, s.steps * s.envs,
              batch_mb);
  Learner learner(o, s, batch_mb);
  std::printf("bench_ingest: path: batch reader (learner QoS and size bound) -> Ingest -> %s\n",
              learner.path().describe().c_str());
  std::printf("bench_ingest: %d sender processes, %.1f s measured per step after %.1f s warm-up\n", o.senders,
              o.seconds, o.warmup);
  std::vector<LearnerShape> shapes;
  if (o.learner != "ingest-thread") shapes.push_back(LearnerShape::kOneThread);
  if (o.learner != "one-thread") shapes.push_back(LearnerShape::kIngestThread);
  std::printf("bench_ingest: learner %s: %s\n", o.learner.c_str(),
              o.learner == "both" ? "each step with one-thread (the loop takes up to 256 batches, then updates), then "
                                    "ingest-thread (IngestThread takes; the loop pops up to 256, then updates)"
              : o.learner == "one-thread"
                  ? "the loop takes up to 256 batches off the reader, then updates"
                  : "IngestThread takes; the loop pops up to 256 accepted batches, then updates");
  std::unique_ptr<Updater> updates;
  if (o.with_updates) {
    updates = std::make_unique<Updater>(s);
    updates->alone(o.warmup);
    std::printf("bench_ingest: update loop %s, 1 thread; 'base' is its rate alone, measured just before each step\n",
                updates->describe().c_str());
  }
  std::printf("%-13s %10s %10s %10s %8s %6s %8s %8s %10s %8s  %s\n", "learner", "offered/s", "taken/s", "MB/s",
              "steps/s", "lost", "invalid", "base/s", "updates/s", "vs base", "verdict");
  struct Verdicts {
    bool ceiling_found = false, any_ok = false;
    int past_ceiling = 0;  // steps in a row past the ceiling
    Step last_ok;
  };
  std::vector<Verdicts> verdicts(shapes.size());
  bool all_ok = true;
  for (size_t i = 0; i < o.rates.size(); ++i) {
    bool all_past = true;
    for (size_t k = 0; k < shapes.size(); ++k) {
      Verdicts& v = verdicts[k];
      if (v.past_ceiling >= 2) continue;
      const double baseline = updates ? updates->alone(o.seconds) : 0.0;
      const Step r = learner.run(int(i), o.rates[i], shapes[k], updates.get());
      const bool behind = r.taken < (1 - o.tolerance) * r.offered;
      const bool slowed = updates && r.updates < (1 - o.max_update_drop) * baseline;
      const bool bad = r.failed || r.lost > 0 || r.invalid > 0 || r.duplicate > 0;
      std::string verdict = r.failed ? "FAILED" : behind ? "CEILING (taken < offered)" : "keeps up";
      if (!r.failed && slowed) verdict += behind ? ", updates slowed" : ", CEILING (updates slowed)";
      char base[32] = "-", upd[32] = "-", vs[32] = "-";
      if (updates) {
        std::snprintf(base, sizeof base, "%.1f", baseline);
        std::snprintf(upd, sizeof upd, "%.1f", r.updates);
        std::snprintf(vs, sizeof vs, "%.3f", baseline > 0 ? r.updates / baseline : 0.0);
      }
      std::printf("%-13s %10.1f %10.1f %10.3f %8.0f %6llu %8llu %8s %10s %8s  %s\n", shape_name(shapes[k]), r.offered,
                  r.taken, r.mbps, r.taken * s.steps * s.envs, (unsigned long long)r.lost,
                  (unsigned long long)(r.invalid + r.duplicate), base, upd, vs, verdict.c_str());
      std::fflush(stdout);
      all_ok = all_ok && !bad && !behind;
      v.past_ceiling = (r.failed || behind || slowed) ? v.past_ceiling + 1 : 0;
      if (!r.failed && !behind && !slowed && !v.ceiling_found) {
        v.last_ok = r;
        v.any_ok = true;
      } else if (!v.ceiling_found) {
        v.ceiling_found = true;
      }
      all_past = all_past && v.past_ceiling >= 2;
    }
    if (all_past) break;
  }
  for (size_t k = 0; k < shapes.size(); ++k) {
    const Verdicts& v = verdicts[k];
    if (v.any_ok)
      std::printf("bench_ingest: %s: highest step kept up: %.1f batches/s, %.3f MB/s, %.0f env steps/s%s\n",
                  shape_name(shapes[k]), v.last_ok.taken, v.last_ok.mbps, v.last_ok.taken * s.steps * s.envs,
                  v.ceiling_found ? "" : " (no ceiling within the rates tried)");
    else
      std::printf("bench_ingest: %s: no step kept up\n", shape_name(shapes[k]));
  }
  if (o.expect_all && !all_ok) {
    std::fprintf(stderr, "bench_ingest: --expect-all: a step did not take everything offered, or lost or refused\n");
    return 1;
  }
  return 0;
}

}  // namespace
}  // namespace bench_ingest

int main(int argc, char** argv) {
  bench_ingest::Options o;
  farm::cli::App app("bench_ingest");
  bench_ingest::add_options(app, o);
  if (const int rc = farm::cli::parse(app, argc, argv); rc >= 0) return rc;
  try {
    bench_ingest::check_combinations(o);
    if (!o.bus.profiles_file.empty()) setenv("FASTRTPS_DEFAULT_PROFILES_FILE", o.bus.profiles_file.c_str(), 1);
    return o.sender ? bench_ingest::run_sender(o) : bench_ingest::run_learner(o);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_ingest: %s\n", e.what());
    return 2;
  }
}
