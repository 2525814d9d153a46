// The learner's ExperimentSpec on the bus: what workers need to join (config, shapes, batch
// sizes, seed, a session id drawn for this learner process, so workers can tell a restarted
// learner) and whether the experiment has finished. Both learners
// (off-policy and PPO) publish through it.
#pragma once

#include <cstdint>

#include "dds.h"
#include "farm.h"
#include "farmPubSubTypes.h"
#include "farm_config.pb.h"

namespace farm {

class SpecPublisher {
 public:
  SpecPublisher(farm::dds::Bus& bus, const config::ExperimentConfig& cfg, int obs_dim, int act_dim);

  // Writes the spec now.
  void publish(bool finished);
  // While the experiment runs: writes it again every dds::kSpecRepublishSeconds, so a worker
  // that missed the durable sample still gets one.
  void republish_if_due(double now);

 private:
  farm::dds::Writer<farm::msg::ExperimentSpec, farm::msg::ExperimentSpecPubSubType> out_;
  farm::msg::ExperimentSpec spec_;
  double last_ = -1e300;
};

}  // namespace farm
