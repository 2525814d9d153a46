// The learner's algorithms, one registration line each (registry.cpp), as robots/task.cpp lists
// the tasks. The learner's dispatch, the programs that read a trained run (off-policy adapters, or
// an algorithm's read_policy) and the tests read this one list; the config check reads the algorithm sections of
// common/farm_config.proto, and a unit test holds the two together.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "algorithm.h"
#include "farm_config.pb.h"
#include "mlp.h"
#include "off_policy.h"
#include "task_spec.h"

namespace farm {

struct AlgorithmRegistration {
  const char* name;  // the config's `algorithm`, and the name of its config section
  // An algorithm with its own driver (PPO); null for an off-policy one.
  std::unique_ptr<Algorithm> (*make)(const config::ExperimentConfig&, const robots::TaskSpec&);
  // An off-policy algorithm: the adapter the replay-buffer driver runs; null otherwise.
  std::unique_ptr<OffPolicy> (*make_off_policy)(const config::ExperimentConfig&, const robots::TaskSpec&);
  // An algorithm with its own driver: its policy as the workers run it, read from the networks it
  // saved in a folder (its checkpoint sub-folder; "" for the networks as it starts), and their update
  // count, for the programs that read a trained run (tools/run_policy.cpp). Null for an off-policy
  // one: those programs load its adapter.
  PolicyParams (*read_policy)(const config::ExperimentConfig&, const robots::TaskSpec&, const std::string& dir,
                              uint64_t version, int64_t* updates);
};

const std::vector<AlgorithmRegistration>& algorithms();
std::vector<std::string> algorithm_names();
// The registration of cfg.algorithm(); throws std::invalid_argument naming the known ones.
const AlgorithmRegistration& find_algorithm(const std::string& name);
// The learner's side of cfg.algorithm() for a task of this spec.
std::unique_ptr<Algorithm> make_algorithm(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec);
// The policy of cfg's algorithm as the workers run it, numbered version: its networks read from dir
// (a checkpoint or best folder, in the algorithm's sub-folder) or, with an empty dir, as its learner
// initializes them; on the CPU whatever device they trained on. *updates: their update count.
// Throws std::runtime_error naming a network file that is missing.
PolicyParams read_saved_policy(config::ExperimentConfig cfg, const robots::TaskSpec& spec, const std::string& dir,
                               uint64_t version, int64_t* updates);

}  // namespace farm
