#include "weight_publisher.h"

#include <stdexcept>

#include "meter.h"

namespace farm {

WeightPublisher::WeightPublisher(farm::dds::Bus& bus, const std::string& experiment_id)
    : experiment_id_(experiment_id),
      weights_out_(bus, farm::dds::kWeightsTopic, "latest_writer"),
      stats_out_(bus, farm::dds::kLearnerStatsTopic, "status_writer") {}

void WeightPublisher::publish(const PolicyParams& policy, uint32_t batch_quota) {
  farm::msg::PolicyWeights w;
  farm::dds::to_wire(policy, experiment_id_, w);
  if (batch_quota > 0) w.batch_quota(batch_quota);
  // Workers refuse larger weights before reading them (dds::kMaxPolicyBytes); the first publish
  // comes at the start, so a network too large for them ends the run there, saying so.
  const uint64_t bytes = 4 * (uint64_t(w.parameters().size()) + w.obs_mean().size() + w.obs_std().size() +
                              w.log_std().size() + w.layer_sizes().size()) +
                         4096;
  if (bytes > farm::dds::kMaxPolicyBytes)
    throw std::runtime_error("the policy is " + std::to_string(bytes) + " bytes on the bus, more than the " +
                             std::to_string(farm::dds::kMaxPolicyBytes) + " a worker takes: a smaller network");
  weights_out_.write(w);
  last_ = std::move(w);
  written_ = true;
  last_time_ = now_seconds();
}

void WeightPublisher::republish_if_due(double now) {
  if (!written_ || now - last_time_ < farm::dds::kWeightsRepublishSeconds) return;
  weights_out_.write(last_);
  last_time_ = now;
}

}  // namespace farm
