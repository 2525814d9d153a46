// The farm-worker service (worker_app.h): the experiment it follows, the policy it runs, the
// batches it collects and the status it beats; its parts send the batches (batch_sender.cpp), run
// the evaluations (evaluations.cpp) and re-send the status while the loop is busy (heartbeat.cpp).
#include "worker_app.h"

#include <sys/resource.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <memory>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "config.h"
#include "printable.h"
#include "shm_leftovers.h"
#include "task.h"
#include "task_specs.h"

namespace farm {

namespace {

constexpr size_t kMaxForeignNoted = 16;

uint64_t fnv1a(const std::string& s) {
  uint64_t h = 1469598103934665603ull;
  for (unsigned char c : s) {
    h ^= c;
    h *= 1099511628211ull;
  }
  return h;
}

}  // namespace

WorkerApp::WorkerApp(const WorkerOptions& o, const std::atomic<bool>& stop)
    : opt_(o),
      stop_(stop),
      bus_(o.bus, "farm-worker " + o.id),
      intake_(bus_, o.experiment),
      sender_(bus_, o.id, {o.inject_nan_batch, o.inject_publish_delay_ms}, stop,
              [this](const std::string& m) { log(m); }),
      evals_(
          bus_, o.id, [this](const std::string& m) { log(m); },
          [this](const std::string& kind, nlohmann::json fields) { events_.write(kind, std::move(fields)); }),
      beat_(bus_),
      session_(farm::dds::random_session_id()),
      experiment_(o.experiment) {
  events_.set_start(now_seconds());
  if (!o.events.empty()) events_.open(o.events);
}

int WorkerApp::run() {
  log("started: session " + std::to_string(session_) + ", domain " + std::to_string(bus_.domain()) + " (" +
      bus_.participant_label() + ")" + (experiment_.empty() ? "" : ", experiment '" + experiment_ + "'") +
      ", DDS profiles " + bus_.profiles_file() +
      (bus_.security_dir().empty() ? "" : ", DDS Security from " + bus_.security_dir()));
  const farm::dds::ShmLeftovers removed = farm::dds::removed_by_this_process();
  events_.write("start", {{"worker_id", opt_.id},
                          {"session", session_},
                          {"domain", bus_.domain()},
                          {"experiment", experiment_},
                          {"security_dir", bus_.security_dir()},
                          {"participant_id", bus_.participant_id() >= 0 ? nlohmann::json(bus_.participant_id())
                                                                        : nlohmann::json(nullptr)},
                          {"shm_segments_removed", removed.segments},
                          {"shm_bytes_removed", removed.bytes}});
  sender_.start();
  beat_.start();
  double last_wait_note = -1e9;
  while (!stop_) {
    poll_spec();
    if (finished_) break;
    if (evals_.arrived())
      evals_.poll({experiment_, rollout_ ? joined_.task : nullptr, joined_.eval_max_episodes, session_,
                   farm::dds::participant_key(joined_.learner_writer)});
    if (!rollout_) {
      state_ = "waiting_for_learner";
      if (now_seconds() - last_wait_note > 5.0) {
        log("waiting for a learner: no ExperimentSpec" +
            (experiment_.empty() ? std::string() : " of experiment '" + experiment_ + "'") + " on DDS domain " +
            std::to_string(bus_.domain()) + " yet (discovery profile " + bus_.profiles_file() +
            ": a learner started with another one is not found)");
        events_.write("waiting", {{"for", "learner"}});
        last_wait_note = now_seconds();
      }
      heartbeat();
      intake_.wait_for_spec(0.2);
      continue;
    }
    poll_weights();
    // The learner's quota for this version (PPO: how much the next fit needs), else the spec's cap.
    const uint32_t cap = quota_.quota > 0 ? quota_.quota : joined_.spec.max_batches_per_version();
    if (!quota_.have_policy || quota_.sent_on_version >= cap) {
      // No weights yet, or this version has produced its share: wait for the next one.
      state_ = quota_.have_policy ? "throttled" : "waiting_for_weights";
      heartbeat();
      const double t = now_seconds();
      intake_.wait_for_weights(0.05);
      tp_.throttled_s += now_seconds() - t;
      continue;
    }
    if (sender_.learners_matched() == 0) {
      // Nobody would receive the batch: hold on rather than lose it.
      state_ = "waiting_for_learner";
      heartbeat();
      const double t = now_seconds();
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
      tp_.throttled_s += now_seconds() - t;
      continue;
    }
    RolloutBatch* buffer = sender_.free_buffer(0.05);
    if (!buffer) {
      // Both buffers still wait for the sender (a full history: the learner is behind).
      state_ = "backpressure";
      heartbeat();
      continue;
    }
    state_ = "running";
    rollout_->collect(static_cast<int>(joined_.spec.steps_per_batch()), *buffer);
    tp_.steps.add(static_cast<uint64_t>(buffer->T) * buffer->N);
    ++quota_.sent_on_version;
    sender_.hand_over(stream());
    heartbeat();
  }
  finish();
  return exit_code_;
}

void WorkerApp::log(const std::string& s) {
  // Lines quote what came from the bus (experiment ids, config errors): made printable and cut, so
  // no escape sequence a participant sends reaches the operator's terminal.
  std::printf("[worker %s] %s\n", opt_.id.c_str(), printable(s, 8192, false).c_str());
  std::fflush(stdout);
}

void WorkerApp::poll_spec() {
  for (const auto& s : intake_.take_specs()) {
    on_spec(s);
    if (finished_) return;
  }
  // The joined learner has left the bus (its lease ran out, or it ended without a last word): the
  // latest spec of another writer is the experiment's learner now, a restarted one.
  if (joined_.pending && rollout_ && !intake_.spec_writer_matched(joined_.learner_writer)) {
    SpecIn next = std::move(*joined_.pending);
    joined_.pending.reset();
    const std::string why = check_spec_update(next.spec);
    if (!why.empty()) return refuse_spec(why);
    if (next.spec.learner_session() != joined_.spec.learner_session()) learner_restarted(next.spec);
    joined_.learner_writer = next.writer;
    intake_.bind_learner(next.writer);
    joined_.spec = next.spec;
  }
}

void WorkerApp::refuse_spec(const std::string& why) {
  ++refusals_.specs;
  // What a participant sends is not for it to fill this worker's log: one line per 10 s at most.
  if (!refusals_.spec_note.due()) return;
  log("refused a spec of experiment '" + experiment_ + "' (" + std::to_string(refusals_.specs) + " so far): " + why);
  events_.write("spec_refused", {{"experiment_id", experiment_}, {"count", refusals_.specs}, {"reason", why}});
}

void WorkerApp::learner_restarted(const farm::msg::ExperimentSpec& s) {
  log("learner restarted; carrying on");
  events_.write("learner_restarted", {{"learner_session", s.learner_session()}});
}

std::string WorkerApp::check_spec_update(const farm::msg::ExperimentSpec& s) const {
  // The learner republishes its spec every few seconds with the same config text: that text was
  // checked when the running spec came, and is parsed again only when it changed.
  if (s.config_text() != joined_.spec.config_text()) {
    config::ExperimentConfig cfg;
    try {
      cfg = robots::parse_config_from_bus(s.config_text(), "ExperimentSpec(" + s.experiment_id() + ")");
    } catch (const std::exception& e) {
      return e.what();
    }
    if (cfg.task().SerializeAsString() != joined_.task_section)
      return "its task section differs from the one this worker runs";
  }
  if (s.steps_per_batch() < 1 || s.steps_per_batch() > uint32_t(kMaxStepsPerBatch) ||
      (long long)s.steps_per_batch() * joined_.envs > kMaxBatchTransitions)
    return "steps_per_batch " + std::to_string(s.steps_per_batch()) + " x " + std::to_string(joined_.envs) +
           " envs is outside 1.." + std::to_string(kMaxStepsPerBatch) + " steps and " +
           std::to_string(kMaxBatchTransitions) + " transitions per batch";
  if (s.max_batches_per_version() < 1) return "max_batches_per_version 0: no batch could be sent";
  const robots::TaskSpec& ts = joined_.task->spec();
  if (int(s.obs_dim()) != ts.obs_dim || int(s.act_dim()) != ts.act_dim)
    return "its obs_dim " + std::to_string(s.obs_dim()) + " / act_dim " + std::to_string(s.act_dim()) +
           " are not the task's " + std::to_string(ts.obs_dim) + " / " + std::to_string(ts.act_dim);
  return "";
}

void WorkerApp::on_spec(const SpecIn& in) {
  const farm::msg::ExperimentSpec& s = in.spec;
  if (experiment_.empty()) {
    // Without --experiment the first experiment this worker can run binds it (join); one that is
    // over is no one's to join, and one it cannot run (a forged or broken spec) must not keep it
    // from the next.
    if (!s.finished()) join(in);
    return;
  }
  // One experiment per worker process: another one's spec (a second learner on the domain, or
  // behind a shared Discovery Server) never takes this worker over, and its sequence numbers never
  // restart under a learner that already counted them. When its experiment ends the worker ends
  // too, so serving a new experiment always starts a new process with a new session.
  if (s.experiment_id() != experiment_) {
    note_foreign(s.experiment_id());
    return;
  }
  if (!rollout_) {
    if (!s.finished()) join(in);
    return;
  }
  // Joined: only the learner joined speaks for the experiment. Another writer's spec (an impostor,
  // or a restarted learner while the old one is still on the bus) waits until that learner has
  // left; another writer's end of the experiment is not believed at all.
  if (in.writer != joined_.learner_writer) {
    if (s.finished()) return refuse_spec("an end of the experiment from a participant other than its learner");
    joined_.pending = in;
    return;
  }
  if (s.finished()) {
    log("learner finished experiment '" + s.experiment_id() + "'");
    events_.write("learner_finished", {{"experiment_id", printable(s.experiment_id(), 100)}});
    finished_ = true;
    return;
  }
  // Checked every time, as at join: a spec that would size batches past their bounds, stall the
  // worker or change its task is refused, and the worker runs on with the spec it has.
  const std::string why = check_spec_update(s);
  if (!why.empty()) return refuse_spec(why);
  if (s.learner_session() != joined_.spec.learner_session()) learner_restarted(s);
  joined_.spec = s;
}

namespace {

// worker.nice: every thread this process has now (the rollout's, the bus's, the heartbeat's) goes
// to at least that nice value; threads made later inherit it from the thread that makes them.
// Linux keeps a nice value per thread, so one setpriority() call would lower the calling thread
// alone. Returns what the join line says of it; a thread that cannot be lowered is named there.
std::string lower_priority(int nice) {
  if (nice <= 0) return "";
  namespace fs = std::filesystem;
  int lowered = 0, kept = 0;
  std::string failed;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator("/proc/self/task", ec)) {
    const id_t tid = id_t(std::strtoul(e.path().filename().c_str(), nullptr, 10));
    errno = 0;
    const int now = getpriority(PRIO_PROCESS, tid);
    if (errno != 0) continue;  // the thread ended meanwhile
    if (now >= nice) {
      ++kept;
      continue;
    }
    if (setpriority(PRIO_PROCESS, tid, nice) == 0)
      ++lowered;
    else if (errno != ESRCH && failed.empty())
      failed = "thread " + std::to_string(tid) + ": " + std::strerror(errno);
  }
  if (ec) return ", nice not set (/proc/self/task: " + ec.message() + ")";
  std::string note =
      ", nice " + std::to_string(nice) + " (worker.nice) on " + std::to_string(lowered + kept) + " threads";
  if (kept > 0) note += ", " + std::to_string(kept) + " of them already at it or above";
  if (!failed.empty()) note += "; not lowered: " + failed;
  return note;
}

}  // namespace

namespace {

// ", each env's noise x U(a, b) per episode" where worker.exploration_scale_min/max set one.
std::string scales_note(const config::WorkerConfig& w) {
  if (w.exploration_scale_min() == 1 && w.exploration_scale_max() == 1) return "";
  char buf[96];
  std::snprintf(buf, sizeof buf, ", each env's noise x U(%g, %g) per episode", w.exploration_scale_min(),
                w.exploration_scale_max());
  return buf;
}

}  // namespace

void WorkerApp::join(const SpecIn& in) {
  const farm::msg::ExperimentSpec& s = in.spec;
  // Batches of an earlier join keep their session; the numbering restarts below.
  sender_.drain(false, [this] { heartbeat(); });
  try {
    config::ExperimentConfig cfg =
        robots::parse_config_from_bus(s.config_text(), "ExperimentSpec(" + s.experiment_id() + ")");
    int envs = opt_.envs > 0 ? opt_.envs : cfg.worker().envs_per_worker();
    // A spec off the bus sizes this worker's batches: bounded before anything is allocated.
    if (s.steps_per_batch() < 1 || s.steps_per_batch() > uint32_t(kMaxStepsPerBatch) ||
        (long long)s.steps_per_batch() * envs > kMaxBatchTransitions)
      throw std::runtime_error("spec's steps_per_batch " + std::to_string(s.steps_per_batch()) + " x " +
                               std::to_string(envs) + " envs is outside 1.." + std::to_string(kMaxStepsPerBatch) +
                               " steps and " + std::to_string(kMaxBatchTransitions) + " transitions per batch");
    if (s.max_batches_per_version() < 1)
      throw std::runtime_error("spec's max_batches_per_version 0: no batch could be sent");
    std::shared_ptr<const robots::Task> task = robots::make_task(cfg.task());
    const int eval_max = std::max(cfg.eval().episodes(), cfg.eval().final_episodes());
    if (task->spec().obs_dim != int(s.obs_dim()) || task->spec().act_dim != int(s.act_dim()))
      throw std::runtime_error("task '" + cfg.task().name() + "' shapes differ from the spec");
    // Sequence numbers restart only with a new session, so no learner counts them duplicate.
    if (sender_.sent() > 0) session_ = farm::dds::random_session_id();
    uint64_t seed = s.seed() ^ fnv1a(opt_.id);
    rollout_ = std::make_unique<Rollout>(task, envs, opt_.threads, seed);
    rollout_->set_exploration_scales(cfg.worker().exploration_scale_min(), cfg.worker().exploration_scale_max());
    if (experiment_.empty()) {
      experiment_ = s.experiment_id();
      intake_.bind(experiment_);
    }
    tp_.at_rollout = {};
    joined_ = {s, task, cfg.task().SerializeAsString(), envs, eval_max, in.writer, std::nullopt};
    intake_.bind_learner(in.writer);
    sender_.restart_numbering();
    quota_ = {};
    last_error_.clear();
    const std::string nice_note = lower_priority(cfg.worker().nice());
    log("joined experiment '" + s.experiment_id() + "': task " + cfg.task().name() + ", " + std::to_string(envs) +
        " envs on " + std::to_string(opt_.threads) + " threads, " + std::to_string(s.steps_per_batch()) +
        " steps per batch" + nice_note + scales_note(cfg.worker()));
    events_.write("joined", {{"experiment_id", s.experiment_id()},
                             {"task", cfg.task().name()},
                             {"envs", envs},
                             {"threads", opt_.threads},
                             {"steps_per_batch", s.steps_per_batch()},
                             {"nice", cfg.worker().nice()},
                             {"session", session_}});
    // Said now, not after the first collect: the beat thread re-sends the last status the loop
    // built, which was the one of a worker waiting for a spec, so a long first collect (mCLARI's:
    // 6-8 s) kept the learner from counting this worker until it ended.
    heartbeat(true);
  } catch (const std::exception& e) {
    // Named for the experiment: the learner reports it (WorkerRoster), this worker having joined none.
    last_error_ = "cannot run experiment '" + s.experiment_id() + "': " + e.what();
    state_ = "error";
    log(last_error_);
    events_.write("join_failed", {{"experiment_id", printable(s.experiment_id(), 100)}, {"error", e.what()}});
    rollout_.reset();
    heartbeat(true);
  }
}

void WorkerApp::note_foreign(const std::string& experiment_id) {
  if (refusals_.foreign.size() >= kMaxForeignNoted || !refusals_.foreign.insert(experiment_id).second) return;
  log("ignores experiment '" + experiment_id + "' on the bus: this worker's experiment is '" + experiment_ + "'" +
      (opt_.experiment.empty() ? " (the first one it joined; --experiment chooses)" : ""));
  events_.write("foreign", {{"experiment_id", printable(experiment_id, 100)}});
}

void WorkerApp::poll_weights() {
  std::vector<std::string> others;
  uint64_t n = 0;  // weights of another participant than the learner, so far
  const std::optional<farm::msg::PolicyWeights> got = intake_.take_weights(&others, &n);
  for (const auto& id : others) note_foreign(id);
  if (n > refusals_.weights) {
    // Another participant publishing this experiment's weights: an impostor, or a restarted learner
    // not yet believed (its spec is, once the joined one has left). Said once per 10 s at most.
    if (refusals_.weights_note.due()) {
      refusals_.weights = n;
      log("weights of experiment '" + experiment_ + "' from a participant other than its learner are not run (" +
          std::to_string(n) + " so far)");
      events_.write("weights_refused", {{"count", n}});
    }
  }
  if (!got) return;
  const farm::msg::PolicyWeights& w = *got;
  if (quota_.have_policy && w.version() == rollout_->policy_version()) {
    quota_.quota = w.batch_quota();  // the same version re-sent: a topped-up quota
    return;
  }
  try {
    PolicyParams p = farm::dds::from_wire(w);
    rollout_->set_policy(p);
    quota_ = {true, 0, w.batch_quota()};
  } catch (const std::exception& e) {
    last_error_ = std::string("bad PolicyWeights: ") + e.what();
    log(last_error_);
  }
}

void WorkerApp::finish() {
  sender_.finishing();
  evals_.stop();  // both may take seconds (an evaluation step, the last batches): still beating
  const auto beat = [this] { heartbeat(); };
  if (!rollout_)
    sender_.drain(true, beat);
  else  // the end of stream goes through the sender's queue, after the last batch
    sender_.end_stream(stream(), joined_.spec.obs_dim(), joined_.spec.act_dim(), rollout_->policy_version(), beat);
  beat_.stop();  // no status of the loop's re-sent after the last one
  state_ = "finished";
  heartbeat(true);
  const uint64_t sent = sender_.sent();
  log("finished: " + std::to_string(sent) + " batches sent (sequence 0.." + std::to_string(sent ? sent - 1 : 0) +
      "), " + std::to_string(tp_.steps.total()) + " env steps, mean " + std::to_string(int64_t(tp_.steps.mean_rate())) +
      " steps/s");
  events_.write("finished", {{"batches_sent", sent},
                             {"last_sequence", sent ? sent - 1 : 0},
                             {"env_steps", tp_.steps.total()},
                             {"mean_steps_per_s", tp_.steps.mean_rate()}});
}

void WorkerApp::heartbeat(bool force) {
  double t = now_seconds();
  if (!force && t - tp_.last_status < 1.0) return;
  double rate = tp_.steps.rate();
  tp_.last_status = t;
  // A worker whose collect loop waits for its quota while the sender still retries a full history
  // is not idle: its batches are on their way.
  const std::string state = sender_.blocked() && state_ == "throttled" ? "backpressure" : state_;
  farm::msg::WorkerStatus s;
  s.worker_id(opt_.id);
  s.worker_session(session_);
  s.host(farm::dds::hostname());
  s.experiment_id(experiment_);
  s.envs(rollout_ ? rollout_->num_envs() : 0);
  s.threads(opt_.threads);
  s.steps_per_second(rate);
  s.env_steps(tp_.steps.total());
  s.batches_sent(sender_.sent());
  s.policy_version(rollout_ ? rollout_->policy_version() : 0);
  s.state(state);
  s.last_error(last_error_.substr(0, farm::dds::kMaxStatusErrorBytes));  // within the learner's bound
  beat_.send(s);
  if (t - tp_.last_log >= opt_.log_every && rollout_) {
    // Steps/s over the same interval as the time split (the heartbeat's rate covers the last second).
    if (tp_.last_log > 0) rate = double(tp_.steps.total() - tp_.log_steps) / (t - tp_.last_log);
    const uint64_t sent = sender_.sent();  // then the steps: collected ahead of what was sent, never behind
    const uint64_t steps = tp_.steps.total();
    const TimeSplit split = time_split(t);
    log(state + ": " + std::to_string(int64_t(rate)) + " steps/s" + split.text() + ", " + std::to_string(sent) +
        " batches sent, " + std::to_string(steps) + " env steps, policy v" +
        std::to_string(rollout_->policy_version()));
    const auto share = [&](double x) { return split.valid ? nlohmann::json(x) : nlohmann::json(nullptr); };
    // The wall-clock time of the line, which scripts set against other processes' clocks.
    const double unix_s = std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
    events_.write("progress", {{"state", state},
                               {"unix_s", unix_s},
                               {"steps_per_s", rate},
                               {"batches_sent", sent},
                               {"env_steps", steps},
                               {"policy_version", rollout_->policy_version()},
                               {"simulate", share(split.simulate)},
                               {"infer", share(split.infer)},
                               {"backpressure", share(split.backpressure)},
                               {"throttled", share(split.throttled)},
                               {"publish", share(split.publish)}});
    tp_.last_log = t;
    tp_.log_steps = steps;
  }
}

// Where the wall time since the last log line went. The collect loop: simulation and policy
// inference (thread time over the rollout's threads, so with one thread the share of wall time the
// worker simulated), waiting for a free buffer (back-pressure: both with the sender) and waiting on
// the learner (throttled: quota spent, no weights or no learner); the rest is bookkeeping. The
// sender thread, beside it: serializing and writing batches, retries on a full history included.
WorkerApp::TimeSplit WorkerApp::time_split(double t) {
  const Rollout::Timing now = rollout_->timing();
  const double wall = t - tp_.last_log, k = rollout_->num_threads();
  const double publish_s = sender_.publish_seconds(t), backpressure_s = sender_.backpressure_seconds();
  TimeSplit s;
  if (tp_.last_log > 0 && wall > 0) {
    s.valid = true;
    s.simulate = (now.simulate_s - tp_.at_rollout.simulate_s) / k / wall;
    s.infer = (now.infer_s - tp_.at_rollout.infer_s) / k / wall;
    s.backpressure = (backpressure_s - tp_.at_backpressure_s) / wall;
    s.throttled = (tp_.throttled_s - tp_.at_throttled_s) / wall;
    s.publish = (publish_s - tp_.at_publish_s) / wall;
  }
  tp_.at_rollout = now;
  tp_.at_publish_s = publish_s;
  tp_.at_backpressure_s = backpressure_s;
  tp_.at_throttled_s = tp_.throttled_s;
  return s;
}

std::string WorkerApp::TimeSplit::text() const {
  if (!valid) return "";
  auto pct = [](double x) { return std::to_string(int(std::lround(100.0 * x))) + "%"; };
  return " (collect: simulate " + pct(simulate) + ", infer " + pct(infer) + ", backpressure " + pct(backpressure) +
         ", throttled " + pct(throttled) + "; sender: publish " + pct(publish) + ")";
}

}  // namespace farm
