// The learner's algorithms, one registration line each (registry.cpp), as robots/task.cpp lists
// the tasks. The learner, the programs that write a policy file from saved networks, and the tests
// read this one list; the config check reads the algorithm sections of common/farm_config.proto,
// and a unit test holds the two together.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "algorithm.h"
#include "farm_config.pb.h"
#include "mlp.h"
#include "task_spec.h"

namespace farm {

struct AlgorithmRegistration {
  const char* name;  // the config's `algorithm`, and the name of its config section
  // Throws std::invalid_argument when the task's action space does not fit the algorithm.
  std::unique_ptr<Algorithm> (*make)(const config::ExperimentConfig&, const robots::TaskSpec&);
  // How the learner paces it (learner/pacing.h): on-policy, in rounds of batches per policy
  // version within a lag window; off-policy, by a samples-per-insert limit over its replay.
  bool on_policy;
};

const std::vector<AlgorithmRegistration>& algorithms();
std::vector<std::string> algorithm_names();
// The registration of cfg.algorithm(); throws std::invalid_argument naming the known ones.
const AlgorithmRegistration& find_algorithm(const std::string& name);
std::unique_ptr<Algorithm> make_algorithm(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec);
// The policy of cfg's algorithm as the workers run it, numbered version: its networks read from dir
// (a checkpoint or best folder, in the algorithm's sub-folder) or, with an empty dir, as its learner
// initializes them; on the CPU whatever device they trained on. *updates: their update count.
// Throws std::runtime_error naming a network file that is missing.
PolicyParams read_saved_policy(config::ExperimentConfig cfg, const robots::TaskSpec& spec, const std::string& dir,
                               uint64_t version, int64_t* updates);

}  // namespace farm
