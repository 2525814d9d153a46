// A config's policy from the learner's networks (config_policy.h).
#include "config_policy.h"

#include <filesystem>
#include <stdexcept>

#include "config.h"
#include "registry.h"

namespace farm::tools {

RunPolicy config_policy(const std::string& config_path, const std::string& dir) {
  if (!dir.empty() && !std::filesystem::is_directory(dir))
    throw std::runtime_error("checkpoint folder " + dir + " does not exist");
  RunPolicy r = with_task(load_config_file(config_path));
  r.dir = dir;
  r.policy = read_saved_policy(r.config, r.task->spec(), dir, 0, &r.updates);
  return r;
}

}  // namespace farm::tools
