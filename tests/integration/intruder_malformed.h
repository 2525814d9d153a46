// farm_intruder's --malformed mode (intruder_malformed.cpp).
#pragma once

#include <string>

#include "dds.h"

// Writes samples of every farm topic broken one way (kind: bool, length or truncate) for `seconds`
// once matched, and prints how many of each it wrote. Returns the process's exit status.
int send_malformed(farm::dds::Bus& bus, const std::string& id, const std::string& experiment, unsigned obs,
                   unsigned act, const std::string& kind, double seconds);
