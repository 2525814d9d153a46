// The learner's PolicyWeights and LearnerStats on the bus: each policy version in the workers'
// layout with the batch quota it allows per worker (checked first against the size a worker
// takes), and the figures of each progress record for the monitor.
#pragma once

#include <cstdint>
#include <string>

#include "dds.h"
#include "farm.h"
#include "farmPubSubTypes.h"
#include "mlp.h"

namespace farm {

class WeightPublisher {
 public:
  WeightPublisher(farm::dds::Bus& bus, const std::string& experiment_id);

  // Writes `policy`; batch_quota 0: no limit. Throws std::runtime_error, before writing, when the
  // policy is larger on the bus than a worker takes (dds::kMaxPolicyBytes).
  void publish(const PolicyParams& policy, uint32_t batch_quota);
  // Writes the latest weights again if none were written for dds::kWeightsRepublishSeconds.
  void republish_if_due(double now);
  void publish_stats(farm::msg::LearnerStats& stats) { stats_out_.write(stats); }

 private:
  const std::string experiment_id_;
  farm::msg::PolicyWeights last_;  // the latest written
  bool written_ = false;
  double last_time_ = 0;
  farm::dds::Writer<farm::msg::PolicyWeights, farm::msg::PolicyWeightsPubSubType> weights_out_;
  farm::dds::Writer<farm::msg::LearnerStats, farm::msg::LearnerStatsPubSubType> stats_out_;
};

}  // namespace farm
