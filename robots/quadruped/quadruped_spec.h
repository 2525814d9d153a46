// The quadrupeds (A1, Honey Badger, Silver Badger) from their configs alone (no MuJoCo): specs and
// range checks.
#pragma once

#include <string>

#include "farm_config.pb.h"

namespace farm {
// The loader's checks of a quadruped's section, for a config built in code; task names the
// section the config stands for, "a1", "honey_badger" or "silver_badger".
void check_config(const config::LeggedConfig& c, const std::string& task);
}  // namespace farm
