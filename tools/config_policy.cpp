// A policy for a config file's experiment when no manifest names it (config_policy.h).
#include "config_policy.h"

#include <filesystem>
#include <stdexcept>

#include "config.h"
#include "policy_file.h"
#include "policy_shape.h"
#include "task_specs.h"

namespace fs = std::filesystem;

namespace farm::tools {

RunPolicy config_policy(const std::string& config_path, const std::string& dir) {
  if (!dir.empty() && !fs::is_directory(dir)) throw std::runtime_error("checkpoint folder " + dir + " does not exist");
  RunPolicy r = with_task(robots::load_config_file(config_path));
  r.dir = dir;
  if (dir.empty()) {
    r.policy = untrained_policy(r.config, r.task->spec());
    return r;
  }
  const fs::path file = fs::path(dir) / kPolicyFileName;
  if (!fs::exists(file)) {
    std::string networks;
    if (fs::exists(fs::path(dir) / r.config.algorithm()))
      networks = " (it holds the networks in " + (fs::path(dir) / r.config.algorithm()).string() + "/)";
    throw std::runtime_error("no policy file in " + dir + ": " + file.string() + " does not exist" + networks +
                             "; write it with `farm-policy-file --config " + config_path + " " + dir + "`");
  }
  r.policy = read_policy_file(file.string());
  check_fits(r.policy, r.task->spec(), file.string());
  if (r.policy.head != policy_shape(r.config, r.task->spec()).head)
    throw std::runtime_error("policy file " + file.string() + " is not a policy of algorithm '" + r.config.algorithm() +
                             "' that " + config_path + " names (its output head differs)");
  r.updates = int64_t(r.policy.version);
  return r;
}

}  // namespace farm::tools
