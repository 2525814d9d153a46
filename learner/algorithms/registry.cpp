#include "registry.h"

#include <stdexcept>

#include "ppo_algorithm.h"
#include "ppo_policy.h"

namespace farm {

const std::vector<AlgorithmRegistration>& algorithms() {
  // One line per algorithm.
  static const std::vector<AlgorithmRegistration> kAlgorithms = {
      {"sac", nullptr, &make_sac},
      {"dqn", nullptr, &make_dqn},
      {"ppo", &make_ppo, nullptr, &read_ppo_policy},
  };
  return kAlgorithms;
}

std::vector<std::string> algorithm_names() {
  std::vector<std::string> names;
  for (const auto& a : algorithms()) names.emplace_back(a.name);
  return names;
}

const AlgorithmRegistration& find_algorithm(const std::string& name) {
  for (const auto& a : algorithms())
    if (name == a.name) return a;
  std::string known;
  for (const auto& n : algorithm_names()) known += (known.empty() ? "" : ", ") + n;
  throw std::invalid_argument("unknown algorithm '" + name + "'; known algorithms: " + known);
}

std::unique_ptr<Algorithm> make_algorithm(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec) {
  const AlgorithmRegistration& a = find_algorithm(cfg.algorithm());
  if (a.make) return a.make(cfg, spec);
  return make_off_policy_algorithm(a.make_off_policy(cfg, spec), cfg, spec);
}

std::unique_ptr<OffPolicy> make_off_policy(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec) {
  const AlgorithmRegistration& a = find_algorithm(cfg.algorithm());
  if (!a.make_off_policy) {
    std::string known;
    for (const auto& r : algorithms())
      if (r.make_off_policy) known += std::string(known.empty() ? "" : ", ") + "\"" + r.name + "\"";
    throw std::invalid_argument("algorithm \"" + cfg.algorithm() +
                                "\" is not an off-policy algorithm (known: " + known + ")");
  }
  return a.make_off_policy(cfg, spec);
}

}  // namespace farm
