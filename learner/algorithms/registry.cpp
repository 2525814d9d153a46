#include "registry.h"

#include <filesystem>
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

PolicyParams read_saved_policy(config::ExperimentConfig cfg, const robots::TaskSpec& spec, const std::string& dir,
                               uint64_t version, int64_t* updates) {
  namespace fs = std::filesystem;
  const std::string algorithm = cfg.algorithm();
  const AlgorithmRegistration& a = find_algorithm(algorithm);  // unknown: names the known ones
  if (!dir.empty()) {
    const fs::path file = fs::path(dir) / algorithm / (algorithm + ".pt");
    if (!fs::exists(file))
      throw std::runtime_error(file.string() + " does not exist (the networks of algorithm \"" + algorithm +
                               "\", which the experiment runs)");
  }
  cfg.mutable_sac()->set_device("cpu");
  cfg.mutable_ppo()->set_device("cpu");
  const std::string sub = dir.empty() ? std::string() : (fs::path(dir) / algorithm).string();
  if (a.make_off_policy) {
    auto algo = a.make_off_policy(cfg, spec);
    if (!dir.empty()) algo->load(sub);
    *updates = algo->updates();
    return algo->export_policy(version);
  }
  // An algorithm with its own driver reads its networks itself (its registration's read_policy).
  if (a.read_policy) return a.read_policy(cfg, spec, sub, version, updates);
  throw std::runtime_error("cannot make a policy of algorithm \"" + algorithm + "\"" +
                           (dir.empty() ? std::string() : " from " + dir) +
                           ": its registration (learner/algorithms/registry.cpp) has no read_policy");
}

}  // namespace farm
