#include "farm_service.h"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <stdexcept>
#include <thread>

#include "checkpoint.h"
#include "config.h"
#include "eval_answer.h"
#include "meter.h"
#include "policy_file.h"
#include "printable.h"
#include "registry.h"
#include "task_specs.h"

namespace farm {

namespace fs = std::filesystem;

namespace {
// --run-dir, or <run_root>/<experiment_id>.
std::string run_dir_of(const LearnerRunOptions& o, const config::ExperimentConfig& cfg) {
  return o.run_dir.empty() ? (fs::path(cfg.run_root()) / cfg.experiment_id()).string() : o.run_dir;
}
}  // namespace

FarmService::FarmService(const LearnerRunOptions& o, const config::ExperimentConfig& cfg,
                         const std::atomic<bool>& interrupted)
    : opt_(o),
      cfg_(cfg),
      interrupted_(interrupted),
      task_spec_(robots::task_spec(cfg_.task())),
      bus_(o.bus, "farm-learner " + cfg_.experiment_id()),
      spec_(bus_, cfg_, task_spec_.obs_dim, task_spec_.act_dim),
      weights_(bus_, cfg_.experiment_id()),
      intake_(
          bus_,
          [this] {
            Ingest in(cfg_.experiment_id(), task_spec_.obs_dim, task_spec_.act_dim,
                      int(task_spec_.metric_names.size()));
            in.set_num_actions(task_spec_.num_actions);
            in.set_reward_bound(task_spec_.reward_bound, task_spec_.reward_min, task_spec_.reward_max);
            in.set_max_episode_steps(task_spec_.max_episode_steps);
            // Called on the ingest thread; roster_ is made before any batch is taken (start()).
            // The heartbeats that have arrived are taken first (at most every 5 ms: the ingest
            // asks again for every session it holds), so a batch right behind the heartbeat it
            // copied finds the binding.
            in.set_announcer([this, last = std::make_shared<double>(0)](const std::string& id, uint64_t session) {
              if (const double now = now_seconds(); now - *last >= 0.005) {
                *last = now;
                roster_.take_pending();
              }
              const auto w = roster_.find(id + "#" + std::to_string(session));
              return w ? w->view.writer : std::string();
            });
            return in;
          }(),
          static_cast<uint32_t>(std::min<uint64_t>(
              Ingest::max_batch_bytes(task_spec_.obs_dim, task_spec_.act_dim, int(task_spec_.metric_names.size()),
                                      cfg_.worker().steps_per_batch()),
              UINT32_MAX)),
          size_t(cfg_.ingest_queue_mib() * (1 << 20)), [this](const std::string& m) { log(m); }, events_),
      roster_(
          bus_,
          [this] {
            WorkerRoster r(
                cfg_.worker_timeout_seconds(), [this](const std::string& m) { log(m); }, cfg_.experiment_id(),
                cfg_.account_expiry_seconds());
            r.on_event([this](const nlohmann::json& e) { events_.write("worker", e); });
            return r;
          }(),
          [this](const std::string& m) { log(m); }, events_),
      evaluator_(
          bus_, cfg_, task_spec_, roster_, events_, [this](const std::string& m) { log(m); },
          (fs::path(run_dir_of(o, cfg_)) / "evaluating").string()),
      checkpointer_(cfg_, task_spec_, run_dir_of(o, cfg_), events_, [this](const std::string& m) { log(m); }),
      algo_(make_pacing(cfg_, task_spec_)),
      stats_(
          cfg_.experiment_id(), events_, [this](const std::string& m) { log(m); },
          [this](farm::msg::LearnerStats& st) { weights_.publish_stats(st); }) {
  run_dir_ = run_dir_of(opt_, cfg_);
  evaluator_.only_workers_that_delivered([this](const std::string& worker_id, const std::string& participant) {
    return intake_.delivered(worker_id, participant);
  });
}

int FarmService::run() {
  prepare_run_dir();
  // The threads run from here: their events count from the run's restored clock until it starts
  // below (after the warm-up), and batches are checked against the restored version.
  events_.set_start(now_seconds() - elapsed_offset_);
  intake_.start(algo_->version());
  roster_.start();
  Evaluator::drop_snapshot(evaluator_.dir());  // what a learner that crashed mid-evaluation left
  algo_->warm_up(*this);                       // workers are not told of the run yet, so none waits on it
  spec_.publish(false);
  t0_ = now_seconds() - elapsed_offset_;
  events_.set_start(t0_);
  events_.write("start", {{"experiment_id", cfg_.experiment_id()},
                          {"task", cfg_.task().name()},
                          {"algorithm", cfg_.algorithm()},
                          {"obs_dim", task_spec_.obs_dim},
                          {"act_dim", task_spec_.act_dim},
                          {"domain", bus_.domain()},
                          {"security_dir", bus_.security_dir()},  // "" without DDS Security
                          {"resumed", opt_.resume},
                          {"ingest_queue_mib", cfg_.ingest_queue_mib()}});
  algo_->start(*this);
  log("experiment '" + cfg_.experiment_id() + "': task " + cfg_.task().name() + " (obs " +
      std::to_string(task_spec_.obs_dim) + ", act " + std::to_string(task_spec_.act_dim) + "), " + algo_->describe() +
      ", DDS domain " + std::to_string(bus_.domain()) + " (" + bus_.participant_label() + "), run dir " + run_dir_ +
      (bus_.security_dir().empty() ? "" : ", DDS Security from " + bus_.security_dir()));
  // The profile as well as the domain: a worker with other discovery (local.xml is shared memory
  // only) never meets this learner.
  log("waiting for workers: start them with `farm-worker --domain " + std::to_string(bus_.domain()) +
      " --dds-profiles " + fs::absolute(bus_.profiles_file()).string() + "`");

  const double t0 = t0_;
  double last_log = now_seconds(), last_ckpt = now_seconds();
  std::string stop_reason;
  while (stop_reason.empty()) {
    if (interrupted_) {
      stop_reason = "interrupted";
      break;
    }
    work();
    const double now = now_seconds();
    if (now - last_log >= cfg_.log_every_seconds()) {
      size_t n = 0;
      intake_.with_ingest([&](Ingest& in) { n = in.expire(now, cfg_.account_expiry_seconds()); });
      if (n > 0)
        log(std::to_string(n) + " worker stream(s) with no batch for " + fmt("%.0f", cfg_.account_expiry_seconds()) +
            " s retired (account_expiry_seconds)");
      progress(now - t0, now - last_log);
      last_log = now;
    }
    spec_.republish_if_due(now);
    weights_.republish_if_due(now);
    if (now - last_ckpt >= cfg_.checkpoint_every_seconds()) {
      try_checkpoint(now - t0);  // a failure is logged and tried again next period
      last_ckpt = now_seconds();
    }
    stop_reason = should_stop(now - t0);
  }
  const double elapsed = now_seconds() - t0;
  log("stopping: " + stop_reason);
  events_.write("stop", {{"reason", stop_reason}, {"env_steps", intake_.env_steps()}, {"updates", algo_->updates()}});
  if (stop_reason == "interrupted") {
    // Workers stay and wait: a resumed learner picks them up again. What the reader already
    // acknowledged goes into the checkpoint first, or the resumed learner counts it lost.
    drain_before_interrupted_stop();
    Evaluator::drop_snapshot(evaluator_.dir());  // evaluations still out are not waited for
    if (!try_checkpoint(elapsed)) return 1;
    log("checkpoint written; resume with --resume");
    return 130;
  }
  // No training data is made from here on: the workers are held (at most one more batch each,
  // besides those already filled) while the final evaluation runs on one of them.
  // Batches that had arrived before the stop are taken first (for at most a second).
  for (const double t_end = now_seconds() + 1.0; now_seconds() < t_end && drain_batches(1024) > 0;) {
  }
  steps_at_stop_ = intake_.env_steps();
  algo_->hold_workers(*this);
  // What the held workers had made or begun (a batch or two each) arrives within moments; it is
  // taken before the final evaluation, so that a last fit can use it. Until no batch came for half
  // a second, three seconds at most.
  drain_while_arriving(0.5, 3.0);
  // A resumed run counts the evaluations before its checkpoint through the best return it kept.
  evaluated_in_training_ = evaluator_.evaluations() > 0 || !std::isnan(checkpointer_.best());
  if (const std::string n = untrained_stop_note(stop_reason); !n.empty()) log(n);
  algo_->final_evaluation(*this, elapsed);
  wait_for_evaluations();  // on the workers, which stay until the spec says finished
  Evaluator::drop_snapshot(evaluator_.dir());
  spec_.publish(true);
  drain_until_workers_end();
  const bool saved = try_checkpoint(elapsed);
  write_summary(elapsed, stop_reason);
  return saved ? 0 : 1;
}

void FarmService::work() {
  // SIGHUP: the permissions document again (deploy/make-pki.sh --revoke); names it drops are refused.
  if (const std::string reloaded = bus_.reload_grants_if_requested(); !reloaded.empty()) {
    log(reloaded);
    const std::set<std::string> granted = bus_.granted_workers();
    events_.write("grants",
                  {{"note", reloaded}, {"granted", std::vector<std::string>(granted.begin(), granted.end())}});
  }
  const size_t got = drain_batches(256);
  poll_evaluations();
  // A long pass (a PPO fit): what the ingest thread accepted meanwhile, as an event.
  const uint64_t accepted = intake_.accepted(), steps = intake_.env_steps();
  const double t = now_seconds();
  const double wait = algo_->train(*this, got > 0);
  if (const double busy = now_seconds() - t; busy >= kBusyEventS)
    events_.write("busy", {{"seconds", busy},
                           {"batches_accepted", intake_.accepted() - accepted},
                           {"env_steps_accepted", intake_.env_steps() - steps},
                           {"queued", intake_.queued()}});
  if (wait > 0) intake_.wait(wait);
}

size_t FarmService::drain_batches(size_t max) {
  intake_.set_version(algo_->version());
  return intake_.pop(max, [this](AcceptedBatch& a) { take(a); });
}

void FarmService::take(AcceptedBatch& a) {
  const Batch b = a.view();
  if (!algo_->take(b)) return;
  for (const auto& e : a.episodes) returns_.add(e.episode_return);
}

void FarmService::drain_while_arriving(double quiet, double most) {
  for (double t = now_seconds(), quiet_from = t, t_end = t + most; t < t_end && t - quiet_from < quiet;
       t = now_seconds()) {
    if (drain_batches(1024) > 0)
      quiet_from = now_seconds();
    else
      intake_.wait(0.05);
  }
}

void FarmService::publish(const PolicyParams& policy, uint32_t batch_quota) {
  // The ingest thread knows a version before any worker can send a batch made with it.
  intake_.set_version(std::max<uint64_t>(policy.version, algo_->version()));
  weights_.publish(policy, batch_quota);
}

std::vector<Farm::LiveWorker> FarmService::live_workers() const {
  std::vector<LiveWorker> out;
  for (const auto& w : roster_.workers()) {
    if (!w.live) continue;
    const auto& v = w.view;
    out.push_back({v.last.worker_id(), v.last.state(), v.last.policy_version(), int(v.last.envs())});
  }
  return out;
}

FarmFigures FarmService::figures() const {
  const IngestCounters c = intake_.counters();
  FarmFigures f;
  f.env_steps = c.env_steps;
  f.ok = c.ok;
  f.lost = c.lost;
  f.duplicate = c.duplicate;
  f.invalid = c.invalid;
  f.episodes = returns_.total;
  f.workers = live_count();
  f.mean_return = returns_.mean();
  f.best_eval = checkpointer_.best();
  f.best_measure = checkpointer_.measure();
  f.evals_asked = evaluator_.asked();
  f.evals_answered = evaluator_.answered();
  f.evals_lost = evaluator_.lost();
  f.evals_invalid = evaluator_.invalid();
  // Live workers that wait on the learner (for new weights, or for room in the batch queue): the
  // learner is the bottleneck and the workers are held back instead of piling up data.
  for (const auto& w : live_workers()) {
    f.throttled += w.state == "throttled";
    f.backpressure += w.state == "backpressure";
  }
  return f;
}

double FarmService::elapsed() const { return now_seconds() - t0_; }

bool FarmService::try_checkpoint(double elapsed) {
  return checkpointer_.save(
      [&] {
        // The accounts as of the last batch the algorithm took: every batch they count accepted is
        // in what it saves (a resumed learner counts the rest lost, and none silently).
        config::CheckpointManifest accounts;
        intake_.settle([this](AcceptedBatch& a) { take(a); },
                       [&accounts](const Ingest& in) { accounts_to_manifest(in, accounts); });
        config::CheckpointManifest m = base_manifest(algo_->version(), algo_->updates(), elapsed);
        m.MergeFrom(accounts);
        algo_->to_manifest(m);
        return m;
      },
      [this](const std::string& tmp) {
        algo_->save(tmp);
        write_policy_file((fs::path(tmp) / kPolicyFileName).string(), algo_->policy());
      });
}

void FarmService::log(const std::string& s) const {
  // Every line is made printable here too, whatever part of it came from the bus (ids, errors,
  // reasons that quote them), and cut: nothing a participant sends reaches the terminal raw.
  std::printf("[learner] %s\n", printable(s, kMaxLogLine, false).c_str());
  std::fflush(stdout);
}

void FarmService::prepare_run_dir() {
  if (opt_.resume) {
    try {
      resume_from_checkpoint();
    } catch (const std::exception& e) {
      // Said in the run's own events too, for programs that watch it (a refused resume changes
      // nothing else there): only where a run already keeps its events, and never in place of
      // the refusal itself, which goes on up whatever the writing does.
      const fs::path events = fs::path(run_dir_) / "events.jsonl";
      std::error_code ec;
      if (fs::is_regular_file(events, ec)) {
        try {
          EventLog refused;
          refused.open(events.string());
          refused.write("refusal", {{"what", "resume"}, {"reason", e.what()}, {"elapsed_s", nullptr}});
        } catch (const std::exception&) {
        }
      }
      throw;
    }
  } else if (const std::string aside = move_run_dir_aside(run_dir_); !aside.empty()) {
    log("previous run moved to " + aside + " (use --resume to continue a run instead)");
  }
  fs::create_directories(run_dir_);
  stats_.open_csv((fs::path(run_dir_) / "learner.csv").string(), algo_->row_schema());
  events_.open((fs::path(run_dir_) / "events.jsonl").string());
}

void FarmService::resume_from_checkpoint() {
  const std::string& dir = checkpointer_.checkpoint_dir();
  if (!checkpoint_exists(dir)) throw std::runtime_error("--resume: no checkpoint in " + dir);
  const config::CheckpointManifest m = read_manifest(dir, cfg_.experiment_id());
  // What the checkpoint's own config says its state is may not change under it (resume_change).
  if (m.has_config_text()) {
    try {
      const std::string why =
          resume_change(robots::parse_config_text(m.config_text(), "the checkpoint's config"), cfg_);
      if (!why.empty()) throw std::runtime_error("--resume: " + why);
    } catch (const ConfigError& e) {
      // Written by an older learner whose config today's checks refuse: nothing to compare with.
      log("the checkpoint's config does not load today (" + std::string(e.what()) + "): not compared");
    }
  }
  algo_->load(usable_checkpoint(dir));
  elapsed_offset_ = m.elapsed_seconds();
  checkpointer_.resume(m);
  returns_.total = m.episodes();
  intake_.with_ingest([&](Ingest& in) { accounts_from_manifest(m, in, now_seconds()); });
  evaluator_.restore_counts(m.evals_asked(), m.evals_answered(), m.evals_lost(), m.evals_invalid());
  // The first progress line's rates count from the restored counters, not from zero.
  const IngestCounters c = intake_.counters();
  last_counters_ = c;
  log("resumed from " + dir + " " + algo_->resumed(m, c.env_steps));
}

int FarmService::live_count() const { return roster_.live_count(); }

void FarmService::Returns::add(float episode_return) {
  recent.push_back(episode_return);
  if (recent.size() > 100) recent.pop_front();
  ++total;
}

void FarmService::record_evaluation(const EvalReport& report, uint64_t version, int64_t updates, double elapsed) {
  checkpointer_.offer(report, version, updates, elapsed, eval_snapshot_, [&] {
    config::CheckpointManifest m = base_manifest(version, updates, elapsed);
    intake_.with_ingest([&m](const Ingest& in) { accounts_to_manifest(in, m); });
    return m;
  });
}

double FarmService::Returns::mean() const {
  if (recent.empty()) return NAN;
  double s = 0;
  for (float x : recent) s += x;
  return s / double(recent.size());
}

void FarmService::progress(double elapsed, double window) {
  const IngestCounters c = intake_.counters();
  FarmFigures f = figures();
  const IngestCounters& l = last_counters_;
  f.in_rate = double(c.env_steps - l.env_steps) / window;
  f.lag = c.ok > l.ok ? (c.lag_sum - l.lag_sum) / double(c.ok - l.ok) : 0.0;
  last_counters_ = c;
  stats_.period(algo_->progress(*this, f, elapsed));
}

std::string FarmService::should_stop(double elapsed) const {
  if (std::string own = algo_->stop_reason(); !own.empty()) return own;
  const auto& s = cfg_.stop();
  const double last_eval = algo_->last_eval();
  const int64_t updates = algo_->updates();
  if (!goal_reached_.empty()) return goal_reached_;
  if (!std::isnan(s.target_eval_return()) && !std::isnan(last_eval) && last_eval_confirmed_ &&
      last_eval >= s.target_eval_return())
    return "evaluation return " + fmt("%.1f", last_eval) + " reached the target " + fmt("%.1f", s.target_eval_return());
  if (s.max_seconds() > 0 && elapsed >= s.max_seconds()) return "time limit " + fmt("%.0f", s.max_seconds()) + " s";
  if (s.max_env_steps() > 0 && int64_t(intake_.env_steps()) >= s.max_env_steps())
    return "env step limit " + std::to_string(s.max_env_steps());
  if (s.max_updates() > 0 && updates >= s.max_updates()) return "update limit " + std::to_string(s.max_updates());
  return "";
}

config::CheckpointManifest FarmService::base_manifest(uint64_t version, int64_t updates, double elapsed) const {
  config::CheckpointManifest m;
  m.set_experiment_id(cfg_.experiment_id());
  m.set_policy_version(version);
  m.set_updates(updates);
  m.set_elapsed_seconds(elapsed);
  if (!std::isnan(checkpointer_.best())) {
    m.set_best_eval_return(checkpointer_.best());
    m.set_best_eval_measure(checkpointer_.measure());
    if (checkpointer_.best_episodes() >= 0) m.set_best_eval_episodes(checkpointer_.best_episodes());
  }
  m.set_config_text(config_to_text(cfg_));
  m.set_episodes(returns_.total);
  // Every part asked is answered, lost, or still out; those out are lost to a resumed learner.
  m.set_evals_asked(evaluator_.asked());
  m.set_evals_answered(evaluator_.answered());
  m.set_evals_lost(evaluator_.lost() + evaluator_.out());
  m.set_evals_invalid(evaluator_.invalid());
  return m;
}

}  // namespace farm
