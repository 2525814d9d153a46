#include "registry.h"

#include <filesystem>
#include <stdexcept>

namespace farm {

std::unique_ptr<Algorithm> make_sac(const config::ExperimentConfig&, const robots::TaskSpec&);
std::unique_ptr<Algorithm> make_dqn(const config::ExperimentConfig&, const robots::TaskSpec&);
std::unique_ptr<Algorithm> make_ppo(const config::ExperimentConfig&, const robots::TaskSpec&);
std::unique_ptr<Algorithm> make_td3(const config::ExperimentConfig&, const robots::TaskSpec&);
std::unique_ptr<Algorithm> make_fastsac(const config::ExperimentConfig&, const robots::TaskSpec&);

const std::vector<AlgorithmRegistration>& algorithms() {
  // One line per algorithm.
  // clang-format off
  static const std::vector<AlgorithmRegistration> kAlgorithms = {
      {"sac", &make_sac, false},
      {"dqn", &make_dqn, false},
      {"ppo", &make_ppo, true},
      {"td3", &make_td3, false},
      {"fastsac", &make_fastsac, false},
  };
  // clang-format on
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
  return find_algorithm(cfg.algorithm()).make(cfg, spec);
}

PolicyParams read_saved_policy(config::ExperimentConfig cfg, const robots::TaskSpec& spec, const std::string& dir,
                               uint64_t version, int64_t* updates) {
  namespace fs = std::filesystem;
  const std::string algorithm = cfg.algorithm();
  find_algorithm(algorithm);  // unknown: names the known ones
  if (!dir.empty()) {
    const fs::path file = fs::path(dir) / algorithm / (algorithm + ".pt");
    if (!fs::exists(file))
      throw std::runtime_error(file.string() + " does not exist (the networks of algorithm \"" + algorithm +
                               "\", which the experiment runs)");
  }
  cfg.mutable_sac()->set_device("cpu");
  cfg.mutable_dqn()->set_device("cpu");
  cfg.mutable_ppo()->set_device("cpu");
  cfg.mutable_td3()->set_device("cpu");
  cfg.mutable_fastsac()->set_device("cpu");
  auto algo = make_algorithm(cfg, spec);
  if (!dir.empty()) algo->load_networks(dir);
  *updates = algo->updates();
  return algo->policy(version);
}

}  // namespace farm
