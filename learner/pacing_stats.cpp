#include "pacing_stats.h"

namespace farm {
namespace stats {

using T = StatType;

const StatField kElapsed{"elapsed_s", "s", T::Real, "%.2f", "%7.1fs"};
const StatField kEnvSteps{"env_steps", "steps", T::Count, "", "| env steps %.0f"};
const StatField kEnvStepsPerS{"env_steps_per_s", "steps/s", T::Real, "%.1f", "(%.0f/s)"};  // since the last line
// Mean versions between the learner's policy and the one that made each batch, since the last line.
const StatField kPolicyLag{"policy_lag", "versions", T::Real, "%.2f", "lag %.1f"};
const StatField kMeanReturn{"mean_return", "", T::Real, "%.3f", "| return %.1f"};  // the last 100 episodes'
const StatField kBatchesOk{"batches_ok", "batches", T::Count, "", "| batches ok %.0f"};
const StatField kBatchesLost{"batches_lost", "batches", T::Count, "", "lost %.0f"};
const StatField kBatchesDuplicate{"batches_duplicate", "batches", T::Count, "", "dup %.0f"};
const StatField kBatchesInvalid{"batches_invalid", "batches", T::Count, "", "invalid %.0f"};
const StatField kWorkers{"workers", "workers", T::Count, "", "| workers %.0f"};                 // live
const StatField kEvalsAsked{"evals_asked", "evaluations", T::Count, "", "| evals asked %.0f"};  // retries included
const StatField kEvalsAnswered{"evals_answered", "evaluations", T::Count, "", "answered %.0f"};
const StatField kEvalsLost{"evals_lost", "evaluations", T::Count, "", "lost %.0f"};
const StatField kEvalsInvalid{"evals_invalid", "evaluations", T::Count, "", "invalid %.0f"};
// Live workers that wait on the learner: for new weights, or for room in its batch queue.
const StatField kWorkersThrottled{"workers_throttled", "workers", T::Count, "", "| throttled %.0f"};
const StatField kWorkersBackpressure{"workers_backpressure", "workers", T::Count, "", "backpressure %.0f"};

const StatField kUpdates{"updates", "updates", T::Count, "", "| updates %.0f"};
const StatField kBufferFill{"buffer_fill", "", T::Real, "%.4f", "| buffer %.3f"};  // of capacity, 0 to 1
// The replay pacing's latest published, the round pacing's fitted (of a fit) or collecting.
const StatField kPolicyVersion{"policy_version", "version", T::Count, "", "| v%.0f"};
// The latest evaluation's mean return; of a fit, the evaluation asked at it (filled when answered).
const StatField kEvalReturn{"eval_return", "", T::Real, "%.3f", "eval %.1f"};

const StatField kUpdatesPerS{"updates_per_s", "updates/s", T::Real, "%.1f", "(%.0f/s)"};
const StatField kUpdateToData{"update_to_data", "updates/step", T::Real, "%.4f", "utd %.3f"};
// Samples the updates drew (batch size x step scale, each) per env step received.
const StatField kSamplesPerInsert{"samples_per_insert", "samples/step", T::Real, "%.3f", "spi %.2f"};
const StatField kCriticLoss{"critic_loss", "", T::Real, "%.5g", ""};
const StatField kActorLoss{"actor_loss", "", T::Real, "%.5g", ""};
const StatField kAlpha{"alpha", "", T::Real, "%.5g", ""};                    // SAC's entropy weight, DQN's epsilon
const StatField kStepScale{"step_scale", "", T::Count, "", "| step x%.0f"};  // sac.max_step_scale's

const StatField kFit{"fit", "fits", T::Count, "", "| fit %.0f"};
const StatField kStepsUsed{"steps_used", "steps", T::Count, "", "| steps used %.0f"};
const StatField kStepsCarried{"steps_carried", "steps", T::Count, "", "carried %.0f"};          // to the next fit
const StatField kStaleDropped{"stale_dropped", "batches", T::Count, "", "stale dropped %.0f"};  // since the last fit
// Versions behind the fitted one, of the steps used: their mean (by steps) and most.
const StatField kLagMean{"lag_mean", "versions", T::Real, "%.3f", "| lag %.2f"};
const StatField kLagMax{"lag_max", "versions", T::Count, "", "max %.0f"};
const StatField kFitSeconds{"fit_seconds", "s", T::Real, "%.3f", "| fit %.2f s"};
const StatField kKl{"kl", "", T::Real, "%.6g", "| kl %.4f"};
const StatField kLearningRate{"learning_rate", "", T::Real, "%.6g", "lr %.3g"};
const StatField kClipFraction{"clip_fraction", "", T::Real, "%.4f", "clip %.3f"};
const StatField kValueLoss{"value_loss", "", T::Real, "%.6g", "| value loss %.4g"};  // a period's: the last fit's
const StatField kPolicyLoss{"policy_loss", "", T::Real, "%.6g", "policy loss %.4g"};
const StatField kEntropy{"entropy", "", T::Real, "%.5g", "entropy %.3f"};
// Of the evaluation asked at a fit, filled when it is answered.
const StatField kEvalMin{"eval_min", "", T::Real, "%.3f", ""};
const StatField kEvalMax{"eval_max", "", T::Real, "%.3f", ""};
const StatField kEvalLength{"eval_length", "steps", T::Real, "%.1f", ""};
const StatField kBatchesStale{"batches_stale", "batches", T::Count, "", "stale %.0f"};  // over the run
const StatField kEpisodes{"episodes", "episodes", T::Count, "", "episodes %.0f"};       // finished since the last fit
const StatField kStepsCollecting{"steps_collecting", "steps", T::Count, "", "collecting %.0f steps"};
const StatField kQuota{"quota", "batches", T::Count, "", "quota %.0f batches/worker"};

StatsSchema replay_schema() {
  return {kElapsed,       kEnvSteps,         kEnvStepsPerS,       kUpdates,
          kUpdatesPerS,   kUpdateToData,     kSamplesPerInsert,   kBufferFill,
          kPolicyVersion, kPolicyLag,        kCriticLoss,         kActorLoss,
          kAlpha,         kMeanReturn,       kEvalReturn,         kBatchesOk,
          kBatchesLost,   kBatchesDuplicate, kBatchesInvalid,     kWorkers,
          kStepScale,     kEvalsAsked,       kEvalsAnswered,      kEvalsLost,
          kEvalsInvalid,  kWorkersThrottled, kWorkersBackpressure};
}

StatsSchema fit_schema(const std::vector<std::string>& metrics) {
  StatField eval = kEvalReturn;
  eval.line = "";  // the fit's line is written before its evaluation is answered
  StatsSchema s{kElapsed,        kFit,          kPolicyVersion, kEnvSteps,   kStepsUsed,   kStepsCarried,
                kStaleDropped,   kLagMean,      kLagMax,        kFitSeconds, kKl,          kLearningRate,
                kClipFraction,   kValueLoss,    kPolicyLoss,    kEntropy,    kMeanReturn,  eval,
                kEvalMin,        kEvalMax,      kEvalLength,    kBatchesOk,  kBatchesLost, kBatchesDuplicate,
                kBatchesInvalid, kBatchesStale, kWorkers,       kEpisodes};
  for (const auto& m : metrics) s.real("train_" + m, "", "%.5g");
  for (const auto& m : metrics) s.real("eval_" + m, "", "%.5g");
  s.add(kWorkersThrottled);
  s.add(kWorkersBackpressure);
  return s;
}

StatsSchema period_schema() {
  return {kElapsed,          kEnvSteps,       kEnvStepsPerS, kPolicyVersion,    kPolicyLag,
          kStepsCollecting,  kQuota,          kUpdates,      kBufferFill,       kValueLoss,
          kPolicyLoss,       kMeanReturn,     kEvalReturn,   kBatchesOk,        kBatchesLost,
          kBatchesDuplicate, kBatchesInvalid, kBatchesStale, kWorkers,          kEvalsAsked,
          kEvalsAnswered,    kEvalsLost,      kEvalsInvalid, kWorkersThrottled, kWorkersBackpressure};
}

}  // namespace stats

void put_figures(StatsRecord& r, const FarmFigures& f, double elapsed) {
  using namespace stats;
  r.set(kElapsed, elapsed);
  r.set(kEnvSteps, double(f.env_steps));
  r.set(kEnvStepsPerS, f.in_rate);
  r.set(kPolicyLag, f.lag);
  r.set(kMeanReturn, f.mean_return);
  r.set(kBatchesOk, double(f.ok));
  r.set(kBatchesLost, double(f.lost));
  r.set(kBatchesDuplicate, double(f.duplicate));
  r.set(kBatchesInvalid, double(f.invalid));
  r.set(kWorkers, f.workers);
  r.set(kEvalsAsked, double(f.evals_asked));
  r.set(kEvalsAnswered, double(f.evals_answered));
  r.set(kEvalsLost, double(f.evals_lost));
  r.set(kEvalsInvalid, double(f.evals_invalid));
  r.set(kWorkersThrottled, f.throttled);
  r.set(kWorkersBackpressure, f.backpressure);
}

}  // namespace farm
