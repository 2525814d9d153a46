// The learner's side of its evaluations (FarmService, farm_service.h): the algorithm asks through
// Farm::ask_evaluation, the Evaluator (evaluator.h) asks the workers and merges their answers, and
// what ended goes back to the algorithm here, with the stop rule's evaluation goal. Training never
// waits for an answer; only the final evaluation is waited for, within eval.answer_timeout_seconds.
#include <algorithm>
#include <cmath>

#include "farm_service.h"
#include "meter.h"

namespace farm {

bool FarmService::ask_evaluation(const PolicyParams& policy, const EvalAsk& ask) {
  return evaluator_.ask(policy, ask, [this](const std::string& dir) { algo_->save_networks(dir); });
}

void FarmService::poll_evaluations() {
  for (auto& d : evaluator_.poll()) report(d);
}

void FarmService::report(Evaluator::Done& d) {
  if (d.given_up) {
    algo_->not_evaluated(*this, d.ask);
  } else {
    last_eval_confirmed_ = d.report.confirmed;
    if (d.ask.label == "eval" && d.report.episodes > 0 && d.report.confirmed) note_goal(d.ask, d.report);
    eval_snapshot_ = &d.snapshot;
    algo_->evaluated(*this, d.ask, d.report);
    eval_snapshot_ = nullptr;
  }
  Evaluator::drop_snapshot(d.snapshot);
}

void FarmService::wait_for_evaluations() {
  if (evaluator_.out() == 0) return;
  const double t0 = now_seconds(), timeout = cfg_.eval().answer_timeout_seconds();
  double last_live = t0;
  log("waiting for " + std::to_string(evaluator_.out()) + " evaluation(s) on the workers (at most " +
      fmt("%.0f", timeout) + " s)");
  while (evaluator_.out() > 0 && !interrupted_) {
    const double now = now_seconds();
    if (live_count() > 0) last_live = now;
    if (now - t0 >= timeout) break;
    if (now - last_live >= cfg_.worker_timeout_seconds()) {
      log("no live worker for " + fmt("%.0f", now - last_live) + " s: the evaluations out are not waited for");
      break;
    }
    drain_batches(256);
    poll_evaluations();
    evaluator_.wait(0.05);
  }
  for (auto& d : evaluator_.give_up_all(now_seconds() - t0)) report(d);
}

// stop.eval_goal: the first training evaluation that meets every bound ends the run (should_stop).
void FarmService::note_goal(const EvalAsk& ask, const EvalReport& rep) {
  const auto& goals = cfg_.stop().eval_goal();
  if (goals.empty() || !goal_reached_.empty()) return;
  std::string met;
  for (const auto& g : goals) {
    const auto it = std::find(task_spec_.metric_names.begin(), task_spec_.metric_names.end(), g.metric());
    const size_t i = size_t(it - task_spec_.metric_names.begin());
    if (i >= rep.metrics.size()) return;
    const double v = rep.metrics[i];
    // Written so that NaN meets no bound.
    if (!std::isnan(g.at_least()) && !(v >= g.at_least())) return;
    if (!std::isnan(g.below()) && !(v < g.below())) return;
    met += (met.empty() ? "" : ", ") + g.metric() + " " + fmt("%.3f", v) +
           (std::isnan(g.at_least()) ? "" : " >= " + fmt("%g", g.at_least())) +
           (std::isnan(g.below()) ? "" : " < " + fmt("%g", g.below()));
  }
  goal_reached_ = "evaluation goal reached: " + met + " (policy v" + std::to_string(ask.version) + ", asked at " +
                  fmt("%.1f", ask.elapsed) + " s)";
  log(goal_reached_);
}

}  // namespace farm
