// LearnerStats' typed fields (idl/farm.idl), declared once: for each, the name of the statistic it
// carries (the learner's statistics record and learner.csv name it so, and farm-monitor's JSON line
// keys it so), its member in farm::msg::LearnerStats and its C++ type, in the IDL's order. The
// learner fills the members from a record by these names (learner/stats_reporter.cpp); farm-monitor
// keeps them in its LearnerRow under the same members and writes them under the same names
// (tools/monitor_snapshot.h). A statistic without a typed field travels only in LearnerStats'
// keyed `stats`.
//   FARM_LEARNER_STATS_FIELDS(X) calls X(name, member, type) for each field.
#pragma once

#include <cstdint>

#define FARM_LEARNER_STATS_FIELDS(X)                \
  X(elapsed_s, elapsed_seconds, double)             \
  X(env_steps, env_steps, uint64_t)                 \
  X(env_steps_per_s, env_steps_per_second, double)  \
  X(updates, updates, uint64_t)                     \
  X(updates_per_s, updates_per_second, double)      \
  X(buffer_fill, buffer_fill, double)               \
  X(policy_lag, policy_lag, double)                 \
  X(critic_loss, critic_loss, double)               \
  X(actor_loss, actor_loss, double)                 \
  X(mean_return, mean_return, double)               \
  X(eval_return, eval_return, double)               \
  X(batches_ok, batches_ok, uint64_t)               \
  X(batches_lost, batches_lost, uint64_t)           \
  X(batches_duplicate, batches_duplicate, uint64_t) \
  X(batches_invalid, batches_invalid, uint64_t)     \
  X(workers, workers, uint32_t)
