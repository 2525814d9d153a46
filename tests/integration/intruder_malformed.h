// farm_intruder's --malformed mode and the batch its modes share (intruder_malformed.cpp).
#pragma once

#include <cstdint>
#include <string>

#include "dds.h"

// A well-formed batch of one step of one environment, worker `id`, session 1, sequence 0: what the
// learner of `experiment` (obs and act its sizes) accepts.
farm::msg::TransitionBatch one_step_batch(const std::string& experiment, const std::string& id, unsigned obs,
                                          unsigned act);

// Writes samples of every farm topic broken one way (kind: bool, length, truncate, or fuzz: each
// sample mutated afresh from fuzz_seed) for `seconds` once matched, and prints how many of each it
// wrote. With dump_dir set it writes nothing to the bus: each topic's broken sample goes to
// dump_dir/<type>_<kind>.hex instead, <type> without its namespace (the regression corpus,
// tests/data/wire_corpus). Returns the process's exit status.
int send_malformed(farm::dds::Bus& bus, const std::string& id, const std::string& experiment, unsigned obs,
                   unsigned act, const std::string& kind, double seconds, uint64_t fuzz_seed = 1,
                   const std::string& dump_dir = "");
