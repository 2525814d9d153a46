// When to fit and when a run ends, with the semantics of MushroomRL's vectorized core as the MushroomRL paper
// §3.1 describes (with the thesis' corrections): a fit is triggered by a number of steps or of
// episodes, a run ends after a number of steps and/or episodes, steps collected beyond a fit
// carry over to the next one, and the mask lets only as many environments run as the fit and the
// run still need, so nothing is generated that the run will not use.
#pragma once

#include <cstdint>

namespace farm {

struct FitPlan {
  int64_t steps_per_fit = 0;  // exactly one of steps_per_fit, episodes_per_fit is > 0
  int64_t episodes_per_fit = 0;
  int64_t steps_per_run = 0;     // 0: no limit
  int64_t episodes_per_run = 0;  // 0: no limit
};

// Throws std::invalid_argument saying which field is wrong.
void check_fit_plan(const FitPlan& p);

// The dataset one fit needs, [rows x cols] = [collection steps x parallel environments], as
// corrected in the MushroomRL paper §3.1: (ceil(N_steps / N_envs) + 1, N_envs) when fitting by steps (+1
// for the steps carried over), (ceil(N_episodes / N_envs) * horizon, min(N_envs, N_episodes))
// when fitting by episodes; not the faulty (N_steps, N_envs).
struct DatasetShape {
  int64_t rows = 0, cols = 0;
};
DatasetShape dataset_shape(const FitPlan& p, int64_t num_envs, int64_t horizon);

class FitScheduler {
 public:
  explicit FitScheduler(const FitPlan& plan);  // check_fit_plan()s it

  // The mask: how many of num_envs environments run the next vectorized step. All of them,
  // except near the end of a run by steps (no step beyond steps_per_run) and when fewer episodes
  // are missing (for the fit or the run) than there are environments.
  int64_t active_envs(int64_t num_envs) const;
  // Steps still to collect for the current fit (steps mode), capped by what the run still
  // allows; in episodes mode, what the run still allows (-1: unbounded).
  int64_t steps_wanted() const;
  // Episodes still to finish for the current fit (episodes mode; -1 in steps mode), capped by
  // what the run still allows.
  int64_t episodes_wanted() const;

  // Accounts collected steps and the episodes that ended in them.
  void on_data(int64_t steps, int64_t episodes_ended);
  // Steps collected toward the next fit and then dropped (made by a version too old): they no
  // longer count toward the fit; they stay in the run's length, they were simulated.
  void forget(int64_t steps);
  // A fit is due when the fit's steps or episodes are in, or the run ended with data left.
  bool fit_due() const;
  struct Fit {
    int64_t steps_used = 0;     // steps that go into this fit
    int64_t steps_carried = 0;  // surplus kept for the next fit
    int64_t episodes = 0;       // episodes that ended in the used data
  };
  // Takes the due fit; the carried steps start the next one.
  Fit take_fit();
  bool run_done() const;
  // Resumes a run: these totals so far, and the steps and episodes collected toward the next fit
  // (a checkpoint's stored rollouts).
  void restore_run(int64_t run_steps, int64_t run_episodes, int64_t fits, int64_t fit_steps = 0,
                   int64_t fit_episodes = 0);

  int64_t fits() const { return fits_; }
  int64_t run_steps() const { return run_steps_; }
  int64_t run_episodes() const { return run_episodes_; }
  int64_t fit_steps() const { return fit_steps_; }  // collected toward the next fit, carry included
  int64_t fit_episodes() const { return fit_episodes_; }
  const FitPlan& plan() const { return plan_; }

 private:
  FitPlan plan_;
  int64_t fit_steps_ = 0, fit_episodes_ = 0, run_steps_ = 0, run_episodes_ = 0, fits_ = 0;
};

}  // namespace farm
