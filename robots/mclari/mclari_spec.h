// The mCLARI microbot from its config alone (no MuJoCo): its spec, its section's range checks and
// the counts that bound its config's lists and indices.
#pragma once

#include "farm_config.pb.h"

namespace farm {

// Phase groups (mCLARI thesis §2.2), the reduced set of them (§4.1.2) and terrains (§3.3); the task
// asserts they agree with its tables (robots/mclari/mclari_task.cpp).
inline constexpr int kMclariPhaseGroups = 27;
inline constexpr int kMclariReducedGroups = 8;
inline constexpr int kMclariTerrains = 6;

// The loader's checks of task.mclari, for a config built in code.
void check_config(const config::MclariConfig& c);

}  // namespace farm
