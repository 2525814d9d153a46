// farm_intruder's modes that send too much: batches of invented streams and heartbeats of invented
// sessions, batches at every bound, and samples of many MiB to the workers (intruder_floods.cpp;
// each mode is described at the top of farm_intruder.cpp).
#pragma once

#include <cstdint>
#include <random>
#include <string>

#include "dds.h"

using BatchWriter = farm::dds::Writer<farm::msg::TransitionBatch, farm::msg::TransitionBatchPubSubType>;

// --oversize 1: makes b a batch of kMaxStepsPerBatch / 16 steps x kMaxEnvsPerWorker envs of a
// session of its own, every field consistent, and prints its serialized size.
void make_oversized(farm::msg::TransitionBatch& b, std::mt19937_64& rng, const std::string& id, unsigned obs,
                    unsigned act);
// --oversize 1: writes b every 500 ms until `seconds` after t0, counting what it wrote in sent and
// the most batch readers matched in max_matched.
void send_oversized(BatchWriter& out, farm::msg::TransitionBatch& b, double t0, double seconds, uint64_t& sent,
                    int& max_matched);
// --hostile 1: every 20 ms one batch numbered near 2^64 or 2^63 and 50 of invented sessions
// numbered anywhere in the 64-bit range, until `seconds` after t0; counted as send_oversized.
void send_hostile(BatchWriter& out, farm::msg::TransitionBatch& b, std::mt19937_64& rng, double t0, double seconds,
                  uint64_t& sent, int& max_matched);
// --flood-streams and --flood-heartbeats: what to send, and the host name of the heartbeats.
struct Flood {
  unsigned streams = 0, heartbeats = 0;
  double beat_every = 0;
  std::string host;
};
// Writes f.streams batches like b, each under an invented worker id and session, and f.heartbeats
// heartbeats of invented sessions (again every f.beat_every seconds while `seconds` last), once
// matched (waiting at most 15 s from t0); prints what it wrote. Returns the exit status.
int flood(farm::dds::Bus& bus, BatchWriter& out, farm::msg::TransitionBatch& b, std::mt19937_64& rng,
          const std::string& id, const std::string& experiment, const Flood& f, double t0, double seconds);
// --big-to-workers MB: one spec, weights and evaluation request of MB MiB each.
int big_to_workers(farm::dds::Bus& bus, const std::string& id, const std::string& experiment, unsigned mib,
                   double seconds);
