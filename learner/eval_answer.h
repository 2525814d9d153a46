// The checks an EvaluationAnswer passes before the learner uses it, and the bound of its size on
// the bus: what the learner asked (experiment, request, worker, version, episodes) against what
// came back, every number finite and every size the experiment's.
#pragma once

#include <cmath>
#include <cstdint>
#include <string>

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
};

// "" when the answer is one to use; else what is wrong with it (the first problem found).
std::string check_eval_answer(const farm::msg::EvaluationAnswer& a, const EvalExpected& e);

// The largest EvaluationAnswer serialized (encapsulation included) for an experiment whose
// evaluations ask at most max_episodes episodes of a task with num_metrics metrics: the learner's
// reader refuses larger samples before memory is taken for them.
uint32_t max_eval_answer_bytes(size_t experiment_id_bytes, int max_episodes, int num_metrics);

}  // namespace farm
