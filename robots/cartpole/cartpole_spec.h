// The cart-pole task from its config alone (no MuJoCo): its spec and its section's range checks.
#pragma once

#include "farm_config.pb.h"

namespace farm {
// The loader's checks of task.cartpole, for a config built in code.
void check_config(const config::CartpoleConfig& c);
}  // namespace farm
