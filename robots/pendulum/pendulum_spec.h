// The pendulum task from its config alone (no MuJoCo): its spec and its section's range checks.
#pragma once

#include "farm_config.pb.h"

namespace farm {
// The loader's checks of task.pendulum, for a config built in code; std::invalid_argument names the
// field ("field 'task.pendulum.mass': expected > 0, got 0").
void check_config(const config::PendulumConfig& c);
}  // namespace farm
