// The checks an EvaluationAnswer passes before the learner uses it, and the bound of its size on
// the bus: what the learner asked (experiment, request, worker, version, episodes) against what
// came back, every number finite and every size the experiment's.
#pragma once

#include <cmath>
#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "dds.h"
#include "farm.h"

namespace farm {

struct EvalExpected {
  std::string experiment_id, worker_id;
  uint64_t learner_session = 0, request_id = 0, worker_session = 0, policy_version = 0;
  int episodes = 0;           // asked
  int num_metrics = 0;        // the task's metric_names.size()
  int max_episode_steps = 0;  // the task's time limit: no episode is longer
  // The task's bound on |reward| of one step (TaskSpec::reward_bound): no episode's return is
  // beyond length x bound. Infinite where the task declares none.
  double reward_bound = HUGE_VAL;
  // The least and the most one step can pay (TaskSpec::reward_min, reward_max): one-sided bounds.
  double reward_min = -HUGE_VAL, reward_max = HUGE_VAL;
};

// "" when the answer is one to use; else what is wrong with it (the first problem found).
std::string check_eval_answer(const farm::msg::EvaluationAnswer& a, const EvalExpected& e);

// Whether the returns of one evaluation, answered in parts by several workers (by worker id), agree:
// they do when at least two workers answered and, for each pair, the difference of their mean returns is
// within `sigmas` standard errors of the mean of the pair's narrower side (plus `relative` of the
// pair's mean size); else `why` says why not. Each side's standard error comes from its own episodes, and the
// narrower one decides: a participant that widens the spread of its own returns widens only its
// own error, never the room the other side's episodes leave, so it cannot make a distant mean
// agree. Under DDS Security a kept best or a stop rests on this.
struct Agreement {
  enum class Verdict { Agree, OneWorker, EmptyPart, Disagree } verdict = Verdict::Agree;
  std::string why;  // "" when they agree
  bool agree() const { return verdict == Verdict::Agree; }
};
Agreement returns_agree(const std::map<std::string, std::vector<double>>& returns_by_worker, double sigmas,
                        double relative);

// The largest EvaluationAnswer serialized (encapsulation included) for an experiment whose
// evaluations ask at most max_episodes episodes of a task with num_metrics metrics: the learner's
// reader refuses larger samples before memory is taken for them.
uint32_t max_eval_answer_bytes(size_t experiment_id_bytes, int max_episodes, int num_metrics);

}  // namespace farm
