// The worker's evaluations (worker_app.h): requests addressed to it are checked and queued, and
// a thread of their own runs each on evaluation envs apart from the training ones.
#include <string>

#include "worker_app.h"

namespace farm {

// Requests addressed to this worker (the listener kept only those): of its experiment, sized within
// what the experiment asks, with a policy that fits the task. Each good one becomes a job for the
// evaluation thread; a bad one is answered with what was wrong (the learner counts it invalid).
void WorkerApp::poll_eval_requests() {
  std::deque<farm::msg::EvaluationRequest> got;
  {
    std::lock_guard<std::mutex> lk(in_mu_);
    got.swap(eval_in_q_);
  }
  for (auto& q : got) {
    if (!rollout_ || q.experiment_id() != experiment_) continue;  // not (yet) this worker's experiment
    log("evaluation request " + std::to_string(q.request_id()) + ": " + std::to_string(q.episodes()) +
        " episodes of policy v" + std::to_string(q.policy_version()));
    if (q.episodes() < 1 || q.episodes() > uint32_t(eval_max_episodes_)) {
      answer_error(q, "episodes " + std::to_string(q.episodes()) + " outside 1.." + std::to_string(eval_max_episodes_) +
                          " (the experiment's eval.episodes / final_episodes)");
      continue;
    }
    if (q.first_episode() > uint32_t(eval_max_episodes_) - q.episodes()) {
      answer_error(q, "first episode " + std::to_string(q.first_episode()) + " + " + std::to_string(q.episodes()) +
                          " episodes past " + std::to_string(eval_max_episodes_) +
                          " (the experiment's eval.episodes / final_episodes)");
      continue;
    }
    if (q.policy().experiment_id() != experiment_ || q.policy().version() != q.policy_version()) {
      answer_error(q, "the policy carried is v" + std::to_string(q.policy().version()) + " of '" +
                          q.policy().experiment_id().substr(0, 64) + "', not v" + std::to_string(q.policy_version()));
      continue;
    }
    EvalJob job;
    try {
      job.policy = farm::dds::from_wire(q.policy());  // its fit to the task: evaluate_policy checks it
    } catch (const std::exception& e) {
      answer_error(q, std::string("bad policy: ") + e.what());
      continue;
    }
    job.task = task_;
    job.worker_session = session_;
    {
      std::lock_guard<std::mutex> lk(eval_mu_);
      if (eval_jobs_.size() >= kMaxEvalQueue) {
        answer_error(q, "busy: " + std::to_string(eval_jobs_.size()) + " evaluations waiting already");
        continue;
      }
      job.request = std::move(q);
      eval_jobs_.push_back(std::move(job));
    }
    if (!eval_thread_.joinable()) eval_thread_ = std::thread([this] { eval_thread_main(); });
    eval_cv_.notify_one();
  }
}

farm::msg::EvaluationAnswer WorkerApp::answer_to(const farm::msg::EvaluationRequest& q, uint64_t session) const {
  farm::msg::EvaluationAnswer a;
  a.experiment_id(q.experiment_id());
  a.learner_session(q.learner_session());
  a.request_id(q.request_id());
  a.worker_id(opt_.id);
  a.worker_session(session);
  a.policy_version(q.policy_version());
  return a;
}

void WorkerApp::answer_error(const farm::msg::EvaluationRequest& q, const std::string& why) {
  log("evaluation request " + std::to_string(q.request_id()) + " refused: " + why);
  farm::msg::EvaluationAnswer a = answer_to(q, session_);
  a.error(why.substr(0, farm::dds::kMaxEvalTextBytes));
  eval_out_.write(a);
}

// The evaluation thread: one job at a time, on evaluation envs made for it (evaluate_policy: one env
// per episode, reset from the request's seed and the episode's number in the whole evaluation),
// never the training envs.
void WorkerApp::eval_thread_main() {
  while (true) {
    EvalJob job;
    {
      std::unique_lock<std::mutex> lk(eval_mu_);
      eval_cv_.wait(lk, [this] { return eval_stop_ || !eval_jobs_.empty(); });
      if (eval_stop_) return;
      job = std::move(eval_jobs_.front());
      eval_jobs_.pop_front();
    }
    const auto& q = job.request;
    farm::msg::EvaluationAnswer a = answer_to(q, job.worker_session);
    const double t0 = now_seconds();
    try {
      const auto recs =
          evaluate_policy(job.task, job.policy, int(q.episodes()), q.seed(), &eval_stop_, q.first_episode());
      if (eval_stop_) return;
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
    while (!eval_out_.write(a) && !eval_stop_) {
    }
    char figures[96];
    std::snprintf(figures, sizeof figures, ": mean return %.1f over %zu episodes (%.1f s)",
                  a.episodes().empty() ? 0.0 : sum / double(a.episodes().size()), a.episodes().size(), a.seconds());
    log("evaluation " + std::to_string(q.request_id()) + " answered" +
        (a.error().empty() ? std::string(figures) : " with an error: " + a.error()));
  }
}

void WorkerApp::stop_eval_thread() {
  {
    std::lock_guard<std::mutex> lk(eval_mu_);
    eval_stop_ = true;
  }
  eval_cv_.notify_all();
  if (eval_thread_.joinable()) eval_thread_.join();
}

}  // namespace farm
