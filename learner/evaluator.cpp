// The learner's evaluations on its workers (evaluator.h).
#include "evaluator.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <iterator>
#include <sstream>

#include "checkpoint.h"
#include "dds.h"
#include "eval_answer.h"
#include "meter.h"
#include "policy_file.h"
#include "printable.h"

namespace farm {

namespace fs = std::filesystem;

namespace {
constexpr size_t kMaxClosedIds = 1024;  // lost or given-up request ids remembered for late answers
constexpr int kMaxEvalRejectionsLogged = 20;
}  // namespace

Evaluator::Evaluator(farm::dds::Bus& bus, const config::ExperimentConfig& cfg, const robots::TaskSpec& spec,
                     const RosterThread& roster, EventLog& events, Log log, std::string dir)
    : Evaluator(
          bus_eval_channel(bus, cfg, spec), cfg, spec, [&roster] { return roster.workers(); }, events, std::move(log),
          std::move(dir)) {}

Evaluator::Evaluator(std::unique_ptr<EvalChannel> channel, const config::ExperimentConfig& cfg,
                     const robots::TaskSpec& spec, Workers workers, EventLog& events, Log log, std::string dir)
    : channel_(std::move(channel)),
      cfg_(cfg),
      spec_(spec),
      workers_(std::move(workers)),
      events_(events),
      log_(std::move(log)),
      dir_(std::move(dir)),
      session_(farm::dds::random_session_id()) {}

bool Evaluator::ask(const PolicyParams& policy, const EvalAsk& ask,
                    const std::function<void(const std::string&)>& keep_networks) {
  if (ask.label != "final") {
    for (auto& r : out_) {
      if (r.ask.label == ask.label) {
        if (r.skips_noted) return false;
        r.skips_noted = true;
        log_("evaluation of policy v" + std::to_string(ask.version) + " not asked: the one of v" +
             std::to_string(r.ask.version) + " is still out, nor any other until it is answered" +
             (r.worker_id.empty()
                  ? " (no live worker yet)"
                  : " (asked of " + r.worker_id + " " + fmt("%.0f", now_seconds() - r.asked_at) + " s ago)"));
        return false;
      }
    }
  }
  const uint64_t g = ++next_group_;
  Group& group = groups_[g];
  group.ask = ask;
  group.policy = policy;
  group.asked_at = now_seconds();
  group.snapshot = (fs::path(dir_) / std::to_string(g)).string();
  try {
    fs::create_directories(group.snapshot);
    keep_networks(group.snapshot);
    write_policy_file((fs::path(group.snapshot) / kPolicyFileName).string(), policy);
  } catch (const std::exception& e) {
    log_("the networks of policy v" + std::to_string(ask.version) + " could not be kept for best/ (" + e.what() +
         "); the evaluation goes on");
    drop_snapshot(group.snapshot);
    group.snapshot.clear();
  }
  // As many parts as there are workers ready now, each of at least min_episodes_per_worker
  // episodes; every part has the evaluation's seed and its first episode numbered after the parts
  // before it, and a worker resets episode k of the evaluation from (seed, k) (evaluate_policy): the
  // evaluation is the same episodes however many parts it is split into (2 workers or 15 are
  // evaluated on the same maps), and a task's evaluation conditions go round the whole evaluation,
  // not each part.
  const int min_each = cfg_.eval().min_episodes_per_worker();
  const int ready = int(ready_workers().size());
  int parts = min_each > 0 ? std::max(1, std::min(ready, ask.episodes / min_each)) : 1;
  // Under security, two workers at least where two are ready (confirmation()).
  if (channel_->secured() && ready >= 2 && ask.episodes >= 2) parts = std::max(parts, 2);
  group.parts = group.parts_left = parts;
  const uint64_t seed = cfg_.seed() + 1000003ull * ++evaluations_;
  bool sent = true;
  int first = 0;
  for (int k = 0; k < parts; ++k) {
    Request r;
    r.id = ++next_id_;
    r.group = g;
    r.part = k + 1;
    r.episodes = ask.episodes / parts + (k < ask.episodes % parts ? 1 : 0);
    r.first_episode = first;
    first += r.episodes;
    r.seed = seed;
    r.ask = ask;
    sent = send(r) && sent;
    out_.push_back(std::move(r));
  }
  if (!sent && !waiting_noted_) {
    log_(ask.label + " evaluation of policy v" + std::to_string(ask.version) +
         " waits for a live worker (none now); training goes on");
    events_.write("eval_waits", {{"label", ask.label}, {"policy_version", ask.version}});
    waiting_noted_ = true;
  }
  return true;
}

std::vector<RosterThread::Worker> Evaluator::ready_workers() const {
  std::vector<RosterThread::Worker> ready;
  for (auto& w : workers_())
    if (w.live && w.view.last.envs() > 0 && w.view.last.state() != "error" &&
        (!delivered_ || delivered_(w.view.last.worker_id(), w.view.writer)))
      ready.push_back(std::move(w));
  return ready;
}

bool Evaluator::send(Request& r) {
  const double now = now_seconds();
  // Live workers that have built their environments, in roster order; the turn goes on from the
  // one asked last, and a retry goes to another worker than the one that lost it where it can.
  const auto ready = ready_workers();
  if (ready.empty()) return false;
  const Group& group = groups_.at(r.group);
  std::vector<RosterThread::Worker> others;
  for (const auto& c : ready)
    if (c.view.last.worker_id() != r.avoid) others.push_back(c);
  const auto& pool = others.empty() ? ready : others;
  auto next = std::find_if(pool.begin(), pool.end(), [this](const auto& c) { return c.key > last_key_; });
  if (next == pool.end()) next = pool.begin();
  last_key_ = next->key;
  r.roster_key = next->key;
  r.worker_id = next->view.last.worker_id();
  r.worker_session = next->view.last.worker_session();
  r.writer = next->view.writer;
  r.asked_at = now;

  farm::msg::EvaluationRequest m;
  m.experiment_id(cfg_.experiment_id());
  m.learner_session(session_);
  m.request_id(r.id);
  m.worker_id(r.worker_id);
  m.policy_version(r.ask.version);
  m.episodes(uint32_t(r.episodes));
  m.seed(r.seed);
  m.first_episode(uint32_t(r.first_episode));
  farm::dds::to_wire(group.policy, cfg_.experiment_id(), m.policy());
  if (!channel_->write(m)) {
    // The reliable history is full (a reader that does not acknowledge): counted as asked, and
    // lost when its time is up.
    log_("evaluation request " + std::to_string(r.id) + " to " + r.worker_id + " could not be written now");
  }
  ++n_.asked;
  waiting_noted_ = false;
  events_.write("ask", {{"request_id", r.id},
                        {"worker_id", r.worker_id},
                        {"label", r.ask.label},
                        {"policy_version", r.ask.version},
                        {"episodes", r.episodes},
                        {"part", r.part},
                        {"parts", group.parts},
                        {"total_episodes", r.ask.episodes},
                        {"attempt", r.attempt},
                        {"first_episode", r.first_episode},
                        {"seed", r.seed}});
  log_("evaluation " + std::to_string(r.id) + " (" + r.ask.label + ", policy v" + std::to_string(r.ask.version) + ", " +
       std::to_string(r.episodes) + " episodes" +
       (group.parts > 1 ? ", part " + std::to_string(r.part) + " of " + std::to_string(group.parts) + ", " +
                              std::to_string(r.ask.episodes) + " in all"
                        : std::string()) +
       (r.attempt > 1 ? ", second try" : "") + ", #" + std::to_string(r.first_episode) + "-" +
       std::to_string(r.first_episode + r.episodes - 1) + " of seed " + std::to_string(r.seed) + ") asked of worker " +
       r.worker_id);
  return true;
}

std::vector<Evaluator::Done> Evaluator::poll() {
  std::vector<Done> done;
  if (out_.empty() && !channel_->matched()) {
    done.swap(done_);
    return done;
  }
  while (channel_->take(answer_, answer_writer_)) take_answer();
  // The roster is copied only while a request is out: poll() runs on every pass of the training
  // loop, and a copy there (up to WorkerRoster::kMaxViews workers, each with its last heartbeat's
  // texts) costs every pass in proportion to a roster that anyone can fill with invented workers.
  if (out_.empty()) {
    done.swap(done_);
    return done;
  }
  const double now = now_seconds(), timeout = cfg_.eval().answer_timeout_seconds();
  const std::vector<RosterThread::Worker> roster = workers_();
  for (size_t i = 0; i < out_.size();) {
    Request& r = out_[i];
    if (r.worker_id.empty()) {
      send(r);
      ++i;
      continue;
    }
    const auto w = std::find_if(roster.begin(), roster.end(), [&r](const auto& c) { return c.key == r.roster_key; });
    const bool dead = w == roster.end() || !w->live;
    if (!dead && now - r.asked_at < timeout) {
      ++i;
      continue;
    }
    Request gone = std::move(r);
    out_.erase(out_.begin() + long(i));
    lost(std::move(gone), dead ? "its worker is no longer live"
                               : "not answered within " + fmt("%.0f", timeout) + " s (eval.answer_timeout_seconds)");
  }
  done.swap(done_);
  return done;
}

void Evaluator::take_answer() {
  // Another learner's, on this domain (another experiment, or one before this on this one): not
  // ours to count. Its request ids may be ours too.
  if (answer_.experiment_id() != cfg_.experiment_id() || answer_.learner_session() != session_) return;
  const auto it =
      std::find_if(out_.begin(), out_.end(), [this](const Request& r) { return r.id == answer_.request_id(); });
  if (it == out_.end() || it->worker_id.empty()) {
    if (closed_.count(answer_.request_id())) {
      ++n_.late;
      log_("evaluation " + std::to_string(answer_.request_id()) + " answered by " + answer_.worker_id().substr(0, 64) +
           " after it was counted lost: not used");
      return;
    }
    ++n_.invalid;
    if (++rejections_logged_ <= kMaxEvalRejectionsLogged)
      log_("refused an evaluation answer from " + answer_.worker_id().substr(0, 64) + ": request " +
           std::to_string(answer_.request_id()) + " was not asked");
    return;
  }
  // Only the participant asked answers: every field of a request can be read off the bus, so an
  // answer that merely matches them may come from anyone. It is bound to the participant whose
  // heartbeats put the worker in the roster (and, under DDS Security, whose certificate bears the
  // worker's id). Not used; the request stays out for the worker asked.
  std::string not_asked;
  if (!it->writer.empty() && answer_writer_.participant != it->writer)
    not_asked = "written by another participant than worker " + it->worker_id + "'s, the one asked";
  else if (channel_->secured() && answer_writer_.certificate_name != it->worker_id)
    not_asked = "written by a participant whose certificate name is '" +
                printable(answer_writer_.certificate_name, 100) + "', not '" + it->worker_id + "'";
  if (!not_asked.empty()) {
    ++n_.invalid;
    if (++rejections_logged_ <= kMaxEvalRejectionsLogged)
      log_("refused an answer to evaluation " + std::to_string(it->id) + ": " + not_asked);
    return;
  }
  EvalExpected e;
  e.experiment_id = cfg_.experiment_id();
  e.learner_session = session_;
  e.worker_id = it->worker_id;
  e.request_id = it->id;
  e.worker_session = it->worker_session;
  e.policy_version = it->ask.version;
  e.episodes = it->episodes;
  e.num_metrics = int(spec_.metric_names.size());
  e.max_episode_steps = spec_.max_episode_steps;
  e.reward_bound = spec_.reward_bound;
  e.reward_min = spec_.reward_min;
  e.reward_max = spec_.reward_max;
  if (const std::string why = check_eval_answer(answer_, e); !why.empty()) {
    // Not used; the request stays out, so it is answered again or counted lost in its time.
    ++n_.invalid;
    if (++rejections_logged_ <= kMaxEvalRejectionsLogged)
      log_("refused the answer to evaluation " + std::to_string(e.request_id) + ": " + why);
    return;
  }
  Request r = std::move(*it);
  out_.erase(it);
  ++n_.answered;
  log_("evaluation " + std::to_string(r.id) + " answered by " + r.worker_id + " (" + fmt("%.1f", answer_.seconds()) +
       " s on the worker, " + fmt("%.1f", now_seconds() - r.asked_at) + " s since asked)");
  events_.write("answer", {{"request_id", r.id},
                           {"worker_id", r.worker_id},
                           {"label", r.ask.label},
                           {"part", r.part},
                           {"episodes", r.episodes},
                           {"worker_seconds", answer_.seconds()},
                           {"since_asked_s", now_seconds() - r.asked_at}});
  // Every part out has its group: giving a group up takes its other parts out (evaluation_given_up).
  const auto g = groups_.find(r.group);
  Group& group = g->second;
  auto& returns = group.returns_by_worker[r.worker_id];
  for (const auto& ep : answer_.episodes()) returns.push_back(ep.episode_return());
  group.episodes.insert(group.episodes.end(), std::make_move_iterator(answer_.episodes().begin()),
                        std::make_move_iterator(answer_.episodes().end()));
  if (--group.parts_left > 0) return;

  EvalReport rep;
  rep.episodes = int(group.episodes.size());
  rep.metrics.assign(e.num_metrics, 0.0);
  rep.metrics_min.assign(e.num_metrics, NAN);
  double sum = 0, len = 0;
  for (const auto& ep : group.episodes) {
    const bool first = &ep == &group.episodes.front();
    sum += ep.episode_return();
    len += ep.length();
    rep.min = std::isnan(rep.min) ? ep.episode_return() : std::min<double>(rep.min, ep.episode_return());
    rep.max = std::isnan(rep.max) ? ep.episode_return() : std::max<double>(rep.max, ep.episode_return());
    for (int k = 0; k < e.num_metrics; ++k) {
      const double v = ep.metrics()[k];
      rep.metrics[k] += v;
      // The lowest episode's value; a NaN (a metric the task cannot compute) makes it NaN, as the mean.
      rep.metrics_min[k] = first                                             ? v
                           : std::isnan(rep.metrics_min[k]) || std::isnan(v) ? NAN
                                                                             : std::min(rep.metrics_min[k], v);
    }
  }
  if (rep.episodes > 0) {
    rep.mean = sum / rep.episodes;
    rep.mean_length = len / rep.episodes;
    for (auto& m : rep.metrics) m /= rep.episodes;
  }
  if (group.parts > 1)
    log_("evaluation of policy v" + std::to_string(group.ask.version) + " complete: " + std::to_string(rep.episodes) +
         " episodes from " + std::to_string(group.parts) + " workers, " + fmt("%.1f", now_seconds() - group.asked_at) +
         " s since asked");
  if (channel_->secured()) {
    const std::string why = confirmation(group);
    rep.confirmed = why.empty();
    if (!rep.confirmed)
      log_("evaluation of policy v" + std::to_string(group.ask.version) + " not confirmed: " + why +
           "; it keeps no best and stops nothing");
  }
  Group done = std::move(group);
  groups_.erase(g);
  {
    const auto num = [](double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr); };
    nlohmann::json metrics = nlohmann::json::object(), metrics_min = nlohmann::json::object();
    for (size_t k = 0; k < spec_.metric_names.size() && k < rep.metrics.size(); ++k) {
      metrics[spec_.metric_names[k]] = num(rep.metrics[k]);
      metrics_min[spec_.metric_names[k]] = num(rep.metrics_min[k]);
    }
    events_.write("evaluation", {{"label", done.ask.label},
                                 {"policy_version", done.ask.version},
                                 {"updates", done.ask.updates},
                                 {"asked_elapsed_s", done.ask.elapsed},
                                 {"episodes", rep.episodes},
                                 {"workers", done.returns_by_worker.size()},
                                 {"mean", num(rep.mean)},
                                 {"min", num(rep.min)},
                                 {"max", num(rep.max)},
                                 {"mean_length", num(rep.mean_length)},
                                 {"metrics", metrics},
                                 {"metrics_min", metrics_min},
                                 {"confirmed", rep.confirmed}});
  }
  done_.push_back({done.ask, rep, done.snapshot, false});
}

void Evaluator::lost(Request r, const std::string& why) {
  count_lost(r, why);
  if (r.attempt == 1) {
    log_("evaluation " + std::to_string(r.id) + " (policy v" + std::to_string(r.ask.version) + ") asked of " +
         r.worker_id + " lost: " + why + "; asked again");
    r.avoid = r.worker_id;
    r.worker_id.clear();
    r.roster_key.clear();
    r.attempt = 2;
    r.id = ++next_id_;
    if (!send(r))
      log_(r.ask.label + " evaluation of policy v" + std::to_string(r.ask.version) + " waits for a live worker");
    out_.push_back(std::move(r));
    return;
  }
  log_("evaluation " + std::to_string(r.id) + " (policy v" + std::to_string(r.ask.version) + ") asked of " +
       r.worker_id + " lost: " + why + "; given up after a second try");
  given_up(r.group);
}

void Evaluator::given_up(uint64_t group) {
  const auto g = groups_.find(group);
  if (g == groups_.end()) return;  // already given up with another of its parts
  Group done = std::move(g->second);
  groups_.erase(g);
  // Its other parts are not waited for: counted lost, and an answer that still comes is late.
  for (auto it = out_.begin(); it != out_.end();) {
    if (it->group != group) {
      ++it;
      continue;
    }
    if (!it->worker_id.empty()) count_lost(*it, "another part of its evaluation was given up");
    it = out_.erase(it);
  }
  events_.write("evaluation",
                {{"label", done.ask.label}, {"policy_version", done.ask.version}, {"episodes", 0}, {"given_up", true}});
  done_.push_back({done.ask, EvalReport{}, done.snapshot, true});
}

std::vector<Evaluator::Done> Evaluator::give_up_all(double waited_seconds) {
  while (!out_.empty()) {
    Request r = std::move(out_.front());
    out_.pop_front();
    if (!r.worker_id.empty()) count_lost(r, "not answered by the end of the run");  // one never asked is not counted
    log_(r.ask.label + " evaluation of policy v" + std::to_string(r.ask.version) + " not answered" +
         (r.worker_id.empty() ? " (no live worker took it)" : " (asked of " + r.worker_id + ")") + " after " +
         fmt("%.0f", waited_seconds) + " s: not reported");
    events_.write("eval_not_answered", {{"label", r.ask.label},
                                        {"policy_version", r.ask.version},
                                        {"worker_id", r.worker_id},  // "": no live worker took it
                                        {"waited_s", waited_seconds}});
    given_up(r.group);
  }
  std::vector<Done> done;
  done.swap(done_);
  return done;
}

void Evaluator::count_lost(const Request& r, const std::string& why) {
  ++n_.lost;
  close_id(r.id);
  events_.write("eval_lost", {{"request_id", r.id},
                              {"worker_id", r.worker_id},
                              {"label", r.ask.label},
                              {"part", r.part},
                              {"attempt", r.attempt},
                              {"why", why}});
}

void Evaluator::close_id(uint64_t id) {
  if (closed_.size() >= kMaxClosedIds) closed_.erase(closed_.begin());
  closed_.insert(id);
}

void Evaluator::drop_snapshot(const std::string& dir) {
  if (dir.empty()) return;
  try {
    remove_tree(dir);  // not fs::remove_all: it crashes the GPU build (checkpoint.cpp)
  } catch (const std::exception&) {
    // a leftover costs only space; the next run's start removes it
  }
}

std::string Evaluator::confirmation(const Group& group) const {
  return returns_agree(group.returns_by_worker, kAgreeSigmas, kAgreeRelative).why;
}

std::string Evaluator::summary() const {
  std::ostringstream o;
  o << "evaluations       asked " << n_.asked << ", answered " << n_.answered << ", lost " << n_.lost << ", invalid "
    << n_.invalid;
  if (n_.late > 0) o << ", late " << n_.late;
  o << " (on the workers)\n";
  return o.str();
}

}  // namespace farm
