#include "fit_scheduler.h"

#include <algorithm>
#include <stdexcept>
#include <string>

namespace farm {

void check_fit_plan(const FitPlan& p) {
  if ((p.steps_per_fit > 0) == (p.episodes_per_fit > 0))
    throw std::invalid_argument("fit plan: set exactly one of steps_per_fit (" + std::to_string(p.steps_per_fit) +
                                ") and episodes_per_fit (" + std::to_string(p.episodes_per_fit) + ") > 0");
  if (p.steps_per_fit < 0 || p.episodes_per_fit < 0)
    throw std::invalid_argument("fit plan: steps_per_fit and episodes_per_fit must be >= 0");
  if (p.steps_per_run < 0 || p.episodes_per_run < 0)
    throw std::invalid_argument("fit plan: steps_per_run and episodes_per_run must be >= 0 (0 = no limit)");
}

DatasetShape dataset_shape(const FitPlan& p, int64_t num_envs, int64_t horizon) {
  check_fit_plan(p);
  if (num_envs <= 0) throw std::invalid_argument("dataset_shape: num_envs must be > 0");
  if (p.steps_per_fit > 0) return {(p.steps_per_fit + num_envs - 1) / num_envs + 1, num_envs};
  if (horizon <= 0) throw std::invalid_argument("dataset_shape: fitting by episodes needs a horizon > 0");
  return {(p.episodes_per_fit + num_envs - 1) / num_envs * horizon, std::min(num_envs, p.episodes_per_fit)};
}

FitScheduler::FitScheduler(const FitPlan& plan) : plan_(plan) { check_fit_plan(plan_); }

int64_t FitScheduler::steps_wanted() const {
  int64_t want = -1;
  if (plan_.steps_per_fit > 0) want = std::max<int64_t>(0, plan_.steps_per_fit - fit_steps_);
  if (plan_.steps_per_run > 0) {
    const int64_t left = std::max<int64_t>(0, plan_.steps_per_run - run_steps_);
    want = want < 0 ? left : std::min(want, left);
  }
  return want;
}

int64_t FitScheduler::episodes_wanted() const {
  int64_t want = -1;
  if (plan_.episodes_per_fit > 0) want = std::max<int64_t>(0, plan_.episodes_per_fit - fit_episodes_);
  if (plan_.episodes_per_run > 0) {
    const int64_t left = std::max<int64_t>(0, plan_.episodes_per_run - run_episodes_);
    want = want < 0 ? left : std::min(want, left);
  }
  return want;
}

int64_t FitScheduler::active_envs(int64_t num_envs) const {
  if (run_done()) return 0;
  int64_t n = num_envs;
  if (plan_.steps_per_run > 0) n = std::min(n, plan_.steps_per_run - run_steps_);
  const int64_t eps = episodes_wanted();
  if (eps >= 0) n = std::min(n, eps);
  return std::max<int64_t>(n, 0);
}

void FitScheduler::on_data(int64_t steps, int64_t episodes_ended) {
  fit_steps_ += steps;
  run_steps_ += steps;
  fit_episodes_ += episodes_ended;
  run_episodes_ += episodes_ended;
}

void FitScheduler::forget(int64_t steps) { fit_steps_ = std::max<int64_t>(0, fit_steps_ - steps); }

bool FitScheduler::run_done() const {
  return (plan_.steps_per_run > 0 && run_steps_ >= plan_.steps_per_run) ||
         (plan_.episodes_per_run > 0 && run_episodes_ >= plan_.episodes_per_run);
}

bool FitScheduler::fit_due() const {
  if (plan_.steps_per_fit > 0 && fit_steps_ >= plan_.steps_per_fit) return true;
  if (plan_.episodes_per_fit > 0 && fit_episodes_ >= plan_.episodes_per_fit) return true;
  return run_done() && fit_steps_ > 0;
}

FitScheduler::Fit FitScheduler::take_fit() {
  Fit f;
  // By steps: at most steps_per_fit (the run's last fit may be shorter); by episodes: all.
  f.steps_used = plan_.steps_per_fit > 0 ? std::min(fit_steps_, plan_.steps_per_fit) : fit_steps_;
  f.steps_carried = fit_steps_ - f.steps_used;
  f.episodes = fit_episodes_;
  fit_steps_ = f.steps_carried;
  fit_episodes_ = 0;
  ++fits_;
  return f;
}

void FitScheduler::restore_run(int64_t run_steps, int64_t run_episodes, int64_t fits, int64_t fit_steps,
                               int64_t fit_episodes) {
  run_steps_ = run_steps;
  run_episodes_ = run_episodes;
  fits_ = fits;
  fit_steps_ = std::max<int64_t>(0, fit_steps);
  fit_episodes_ = std::max<int64_t>(0, fit_episodes);
}

}  // namespace farm
