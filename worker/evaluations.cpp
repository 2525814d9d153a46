#include "evaluations.h"

#include <cstdio>
#include <string>

#include "meter.h"

namespace farm {

Evaluations::Evaluations(farm::dds::Bus& bus, const std::string& worker_id, Log log, Event event)
    : worker_id_(worker_id),
      log_(std::move(log)),
      event_(event ? std::move(event) : [](const std::string&, nlohmann::json) {}),
      // Requests are kept only when addressed to this worker; their contents are checked in poll().
      in_(bus, farm::dds::kEvalRequestTopic, "batch_reader", farm::dds::kMaxEvalRequestBytes,
          [this](eprosima::fastdds::dds::DataReader* r) {
            In in;
            eprosima::fastdds::dds::SampleInfo info;
            while (decltype(in_)::take_from(r, in.request, info)) {
              if (in.request.worker_id() != worker_id_) continue;
              in.participant = farm::dds::participant_key(info.sample_identity.writer_guid());
              // The joined learner's requests have a queue of their own: no other participant's,
              // however many, pushes one of them out before poll() sees it.
              std::lock_guard<std::mutex> lk(in_mu_);
              auto& q = !learner_.empty() && in.participant == learner_ ? in_q_ : others_q_;
              if (q.size() >= kMaxQueue) q.pop_front();
              q.push_back(std::move(in));
            }
          }),
      out_(bus, farm::dds::kEvalAnswerTopic, "batch_writer") {}

// Requests addressed to this worker (the listener kept only those): of its experiment, sized within
// what the experiment asks, with a policy that fits the task. Each good one becomes a job for the
// evaluation thread; a bad one is answered with what was wrong (the learner counts it invalid).
bool Evaluations::arrived() {
  std::lock_guard<std::mutex> lk(in_mu_);
  return !in_q_.empty() || !others_q_.empty() || !held_.empty();
}

void Evaluations::poll(const Joined& joined) {
  std::deque<In> got;
  {
    // The learner's first, then the others' (checked below against the learner joined now, which
    // may have changed since they were queued).
    std::lock_guard<std::mutex> lk(in_mu_);
    got.swap(in_q_);
    for (auto& in : held_) got.push_back(std::move(in));
    held_.clear();
    for (auto& in : others_q_) got.push_back(std::move(in));
    others_q_.clear();
    learner_ = joined.task ? joined.learner : std::string();
  }
  for (auto& in : got) {
    auto& [q, from, held] = in;
    if (!joined.task || q.experiment_id() != joined.experiment) continue;  // not (yet) this worker's experiment
    if (from != joined.learner) {
      // Only the learner the worker joined asks it for evaluations: anyone else's request is neither
      // run nor answered (said once per 10 s at most), but kept aside in case its writer is a
      // restarted learner the worker believes later.
      if (!held) {
        ++not_learners_;
        if (not_learners_note_.due()) {
          log_("evaluation requests from a participant other than the learner are not run (" +
               std::to_string(not_learners_) + " so far)");
        }
      }
      held = true;
      if (held_.size() >= kMaxQueue) held_.pop_front();
      held_.push_back(std::move(in));
      continue;
    }
    log_("evaluation request " + std::to_string(q.request_id()) + ": " + std::to_string(q.episodes()) +
         " episodes of policy v" + std::to_string(q.policy_version()));
    event_("eval_request",
           {{"request_id", q.request_id()}, {"episodes", q.episodes()}, {"policy_version", q.policy_version()}});
    const int most = joined.max_episodes;
    if (q.episodes() < 1 || q.episodes() > uint32_t(most)) {
      answer_error(q, joined.session,
                   "episodes " + std::to_string(q.episodes()) + " outside 1.." + std::to_string(most) +
                       " (the experiment's eval.episodes / final_episodes)");
      continue;
    }
    if (q.first_episode() > uint32_t(most) - q.episodes()) {
      answer_error(q, joined.session,
                   "first episode " + std::to_string(q.first_episode()) + " + " + std::to_string(q.episodes()) +
                       " episodes past " + std::to_string(most) + " (the experiment's eval.episodes / final_episodes)");
      continue;
    }
    if (q.policy().experiment_id() != joined.experiment || q.policy().version() != q.policy_version()) {
      answer_error(q, joined.session,
                   "the policy carried is v" + std::to_string(q.policy().version()) + " of '" +
                       q.policy().experiment_id().substr(0, 64) + "', not v" + std::to_string(q.policy_version()));
      continue;
    }
    Job job;
    try {
      job.policy = farm::dds::from_wire(q.policy());  // its fit to the task: evaluate_policy checks it
    } catch (const std::exception& e) {
      answer_error(q, joined.session, std::string("bad policy: ") + e.what());
      continue;
    }
    job.task = joined.task;
    job.worker_session = joined.session;
    {
      std::lock_guard<std::mutex> lk(mu_);
      if (jobs_.size() >= kMaxQueue) {
        answer_error(q, joined.session, "busy: " + std::to_string(jobs_.size()) + " evaluations waiting already");
        continue;
      }
      job.request = std::move(q);
      jobs_.push_back(std::move(job));
    }
    if (!thread_.joinable()) thread_ = std::thread([this] { main(); });
    cv_.notify_one();
  }
}

farm::msg::EvaluationAnswer Evaluations::answer_to(const farm::msg::EvaluationRequest& q, uint64_t session) const {
  farm::msg::EvaluationAnswer a;
  a.experiment_id(q.experiment_id());
  a.learner_session(q.learner_session());
  a.request_id(q.request_id());
  a.worker_id(worker_id_);
  a.worker_session(session);
  a.policy_version(q.policy_version());
  return a;
}

void Evaluations::answer_error(const farm::msg::EvaluationRequest& q, uint64_t session, const std::string& why) {
  log_("evaluation request " + std::to_string(q.request_id()) + " refused: " + why);
  event_("eval_refused", {{"request_id", q.request_id()}, {"why", why}});
  farm::msg::EvaluationAnswer a = answer_to(q, session);
  a.error(why.substr(0, farm::dds::kMaxEvalTextBytes));
  out_.write(a);
}

// The evaluation thread: one job at a time, on evaluation envs made for it (evaluate_policy: one env
// per episode, reset from the request's seed and the episode's number in the whole evaluation),
// never the training envs.
void Evaluations::main() {
  while (true) {
    Job job;
    {
      std::unique_lock<std::mutex> lk(mu_);
      cv_.wait(lk, [this] { return stop_ || !jobs_.empty(); });
      if (stop_) return;
      job = std::move(jobs_.front());
      jobs_.pop_front();
    }
    const auto& q = job.request;
    farm::msg::EvaluationAnswer a = answer_to(q, job.worker_session);
    const double t0 = now_seconds();
    try {
      const auto recs = evaluate_policy(job.task, job.policy, int(q.episodes()), q.seed(), &stop_, q.first_episode());
      if (stop_) return;
      std::vector<farm::msg::EvaluationEpisode> eps(recs.size());
      for (size_t i = 0; i < recs.size(); ++i) {
        eps[i].episode_return(recs[i].episode_return);
        eps[i].length(uint32_t(recs[i].length));
        eps[i].terminated(recs[i].terminated);
        eps[i].metrics(recs[i].metrics);
      }
      a.episodes(std::move(eps));
    } catch (const std::exception& e) {
      a.error(std::string(e.what()).substr(0, farm::dds::kMaxEvalTextBytes));
    }
    a.seconds(now_seconds() - t0);
    double sum = 0;
    for (const auto& e : a.episodes()) sum += e.episode_return();
    // A full reliable history makes write() time out: retry while the worker runs.
    while (!out_.write(a) && !stop_) {
    }
    char figures[96];
    std::snprintf(figures, sizeof figures, ": mean return %.1f over %zu episodes (%.1f s)",
                  a.episodes().empty() ? 0.0 : sum / double(a.episodes().size()), a.episodes().size(), a.seconds());
    log_("evaluation " + std::to_string(q.request_id()) + " answered" +
         (a.error().empty() ? std::string(figures) : " with an error: " + a.error()));
    event_("eval_answered", {{"request_id", q.request_id()},
                             {"episodes", a.episodes().size()},
                             {"mean_return", a.episodes().empty() ? nlohmann::json(nullptr)
                                                                  : nlohmann::json(sum / double(a.episodes().size()))},
                             {"seconds", a.seconds()},
                             {"error", a.error()}});
  }
}

void Evaluations::stop() {
  {
    std::lock_guard<std::mutex> lk(mu_);
    stop_ = true;
  }
  cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

}  // namespace farm
