// The mobile robots (Jetbot, Kaya) from their configs alone (no MuJoCo): specs and range checks.
#pragma once

#include "farm_config.pb.h"

namespace farm {
// The loader's checks of task.jetbot and task.kaya, their scenes included, for configs built in code.
void check_config(const config::JetbotConfig& c);
void check_config(const config::KayaConfig& c);
}  // namespace farm
