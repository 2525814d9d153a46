// What the pacings report (pacing.h), as statistics records (stats_record.h): every field either
// pacing reports is declared here once, with its name (learner.csv's column), unit, type and
// formats, and the schemas below place them. The runner renders each record as the progress line,
// a row of learner.csv and its progress event, and LearnerStats (stats_reporter.h).
#pragma once

#include <string>
#include <vector>

#include "pacing.h"
#include "stats_record.h"

namespace farm {
namespace stats {

// The runner's figures (FarmFigures), filled by put_figures.
extern const StatField kElapsed, kEnvSteps, kEnvStepsPerS, kPolicyLag, kMeanReturn, kBatchesOk, kBatchesLost,
    kBatchesDuplicate, kBatchesInvalid, kWorkers, kEvalsAsked, kEvalsAnswered, kEvalsLost, kEvalsInvalid,
    kWorkersThrottled, kWorkersBackpressure;
// Both pacings'.
extern const StatField kUpdates, kBufferFill, kPolicyVersion, kEvalReturn;
// The replay pacing's.
extern const StatField kUpdatesPerS, kUpdateToData, kSamplesPerInsert, kCriticLoss, kActorLoss, kAlpha, kStepScale;
// The round pacing's: of a fit, and of a progress period.
extern const StatField kFit, kStepsUsed, kStepsCarried, kStaleDropped, kLagMean, kLagMax, kFitSeconds, kKl,
    kLearningRate, kClipFraction, kValueLoss, kPolicyLoss, kEntropy, kEvalMin, kEvalMax, kEvalLength, kBatchesStale,
    kEpisodes, kStepsCollecting, kQuota;

// The replay pacing's record, one a progress period: learner.csv's columns in order.
StatsSchema replay_schema();
// The round pacing's record of a fit, learner.csv's columns in order; the task's per-episode
// metrics (TaskSpec::metric_names) come after the fixed columns, as means over the episodes
// finished since the last fit (train_<metric>) and over the evaluation's (eval_<metric>).
StatsSchema fit_schema(const std::vector<std::string>& metrics);
// The round pacing's record of a progress period (the progress line and LearnerStats; no row).
StatsSchema period_schema();

}  // namespace stats

// Sets each of the runner's figures that r's schema has, and elapsed_s.
void put_figures(StatsRecord& r, const FarmFigures& f, double elapsed);

}  // namespace farm
