// EvaluationAnswer checks and size bound (eval_answer.h).
#include "eval_answer.h"

#include "config_validator.h"
#include "task_spec.h"

#include <algorithm>
#include <cmath>

namespace farm {

std::string check_eval_answer(const farm::msg::EvaluationAnswer& a, const EvalExpected& e) {
  if (a.experiment_id() != e.experiment_id)
    return "experiment '" + a.experiment_id().substr(0, 64) + "', expected '" + e.experiment_id + "'";
  if (a.learner_session() != e.learner_session)
    return "learner session " + std::to_string(a.learner_session()) + ", this learner's is " +
           std::to_string(e.learner_session);
  if (a.request_id() != e.request_id)
    return "request " + std::to_string(a.request_id()) + ", expected " + std::to_string(e.request_id);
  if (a.worker_id() != e.worker_id)
    return "from worker '" + a.worker_id().substr(0, 64) + "', asked of '" + e.worker_id + "'";
  if (a.worker_session() != e.worker_session)
    return "worker session " + std::to_string(a.worker_session()) + ", asked of session " +
           std::to_string(e.worker_session);
  if (a.policy_version() != e.policy_version)
    return "policy v" + std::to_string(a.policy_version()) + ", asked v" + std::to_string(e.policy_version);
  if (a.error().size() > farm::dds::kMaxEvalTextBytes)
    return "an error text of " + std::to_string(a.error().size()) + " bytes";
  if (!a.error().empty()) return "the worker could not evaluate: " + a.error();
  if (a.episodes().size() != size_t(e.episodes))
    return std::to_string(a.episodes().size()) + " episodes, asked " + std::to_string(e.episodes);
  if (!std::isfinite(a.seconds()) || a.seconds() < 0) return "seconds " + std::to_string(a.seconds());
  for (size_t i = 0; i < a.episodes().size(); ++i) {
    const auto& ep = a.episodes()[i];
    const std::string at = "episode " + std::to_string(i) + ": ";
    if (!std::isfinite(ep.episode_return())) return at + "return is not finite";
    if (ep.length() < 1 || ep.length() > uint32_t(e.max_episode_steps))
      return at + "length " + std::to_string(ep.length()) + " outside 1.." + std::to_string(e.max_episode_steps);
    if (!robots::return_within_bound(ep.episode_return(), ep.length(), e.reward_bound))
      return at + "return " + std::to_string(ep.episode_return()) + " beyond what " + std::to_string(ep.length()) +
             " steps of this task can give (at most " + std::to_string(e.reward_bound) + " a step)";
    if (!robots::return_within_range(ep.episode_return(), ep.length(), e.reward_min, e.reward_max))
      return at + "return " + std::to_string(ep.episode_return()) + " outside what " + std::to_string(ep.length()) +
             " steps of this task can give (each step's reward in [" + std::to_string(e.reward_min) + ", " +
             std::to_string(e.reward_max) + "])";
    if (ep.metrics().size() != size_t(e.num_metrics))
      return at + std::to_string(ep.metrics().size()) + " metrics, the task has " + std::to_string(e.num_metrics);
    for (size_t k = 0; k < ep.metrics().size(); ++k)
      if (!std::isfinite(ep.metrics()[k])) return at + "metric " + std::to_string(k) + " is not finite";
  }
  return "";
}

Agreement returns_agree(const std::map<std::string, std::vector<double>>& by, double sigmas, double relative) {
  using V = Agreement::Verdict;
  if (by.size() < 2)
    return {V::OneWorker,
            "answered by one worker only (" + (by.empty() ? std::string("none") : by.begin()->first) + ")"};
  // Mean and standard error of the mean of one worker's returns.
  const auto stats = [](const std::vector<double>& v) {
    double m = 0, q = 0;
    for (double x : v) m += x;
    m /= double(v.size());
    for (double x : v) q += (x - m) * (x - m);
    const double var = v.size() > 1 ? q / double(v.size() - 1) : 0.0;
    return std::pair<double, double>{m, std::sqrt(var / double(v.size()))};
  };
  for (auto a = by.begin(); a != by.end(); ++a) {
    for (auto b = std::next(a); b != by.end(); ++b) {
      if (a->second.empty() || b->second.empty()) return {V::EmptyPart, "a worker's part has no episodes"};
      const auto [ma, sa] = stats(a->second);
      const auto [mb, sb] = stats(b->second);
      const double room = sigmas * std::min(sa, sb) + relative * 0.5 * (std::abs(ma) + std::abs(mb)) + 1e-6;
      if (!(std::abs(ma - mb) <= room))
        return {V::Disagree, a->first + "'s episodes (mean return " + config_checks::num(ma) + ") and " + b->first +
                                 "'s (" + config_checks::num(mb) + ") disagree by more than " +
                                 config_checks::num(room)};
    }
  }
  return {};
}

uint32_t max_eval_answer_bytes(size_t experiment_id_bytes, int max_episodes, int num_metrics) {
  // Encapsulation and the fixed fields, the strings with their lengths and padding, then each
  // episode: return, length, flag (padded), metrics length and metrics.
  const uint64_t fixed = 4 + 8 * 8 + 3 * (4 + 8) + experiment_id_bytes + 2 * farm::dds::kMaxEvalTextBytes + 4;
  const uint64_t per_episode = 4 + 4 + 1 + 3 + 4 + 4 * uint64_t(std::max(num_metrics, 0));
  return uint32_t(std::min<uint64_t>(fixed + uint64_t(std::max(max_episodes, 0)) * per_episode + 256, UINT32_MAX));
}

}  // namespace farm
