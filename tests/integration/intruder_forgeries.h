// farm_intruder's modes that pass for someone else: answers to evaluations asked of another
// worker, evaluation requests wrong one way each, weights written again under a later version,
// batches under another worker's session, and participant removals in the learner's name
// (intruder_forgeries.cpp; each mode is described at the top of farm_intruder.cpp).
#pragma once

#include <cstdint>
#include <string>

#include "dds.h"

// --forge-answers RETURN [--heartbeat 1 [--deliver 0]]: answers every request of `experiment` the
// moment it is seen.
int forge_answers(farm::dds::Bus& bus, const std::string& id, const std::string& experiment, double seconds,
                  float forged_return, uint32_t length, uint32_t metrics, bool own_heartbeat, unsigned obs,
                  unsigned act, bool deliver);
// --eval-requests WORKER: rounds of requests to `worker`, each wrong in one way, for `seconds` once
// matched; prints how many it sent and how many answers came back.
int bad_eval_requests(farm::dds::Bus& bus, const std::string& id, const std::string& experiment,
                      const std::string& worker, double seconds);
// --forge-weights 1: the experiment's weights written again a million versions ahead.
int forge_weights(farm::dds::Bus& bus, const std::string& id, const std::string& experiment, double seconds);
// --forge-removal 1: raw UDP participant removals in the learner's name, every every_ms.
int forge_removal(farm::dds::Bus& bus, const std::string& id, const std::string& experiment, double seconds,
                  double every_ms);
// --steal-streams 1: batches under each worker session its heartbeats name, numbered from 0.
int steal_streams(farm::dds::Bus& bus, const std::string& id, const std::string& experiment, double seconds,
                  unsigned obs, unsigned act);
