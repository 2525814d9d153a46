// farm_intruder's record for programs (--events FILE; its kinds are listed at the top of
// farm_intruder.cpp).
#pragma once

#include <string>

#include <nlohmann/json.hpp>

// Writes one event of `kind` with `fields` and the participant's id ("id") to the --events file;
// nothing without --events.
void record(const std::string& kind, nlohmann::json fields = nlohmann::json::object());
