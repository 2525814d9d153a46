// Experiment configuration: Protobuf text format checked against the schema in
// farm_config.proto, then against the ranges each field needs. Every error names the file, the
// line and the field.
#pragma once

#include <stdexcept>
#include <string>

#include "farm_config.pb.h"

namespace farm {

struct ConfigError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// Throws ConfigError ("FILE:LINE:COL: field 'sac.batch_size': expected > 0, got -3").
config::ExperimentConfig load_config_file(const std::string& path);
config::ExperimentConfig parse_config_text(const std::string& text, const std::string& source);

// The experiment config as text (what the learner sends to the workers in the ExperimentSpec).
std::string config_to_text(const config::ExperimentConfig& cfg);

// "cpu", "cuda" or "cuda:N" (N a device index): the learner devices a config may name.
bool valid_device_name(const std::string& name);

// Hidden sizes of the SAC networks (the schema's default when the list is empty).
std::vector<int> sac_hidden(const config::SacConfig& sac);
// The critics' hidden sizes: sac.critic_hidden, or sac_hidden() when it is empty.
std::vector<int> sac_critic_hidden(const config::SacConfig& sac);

}  // namespace farm
