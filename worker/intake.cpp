#include "intake.h"

namespace farm {

WorkerIntake::WorkerIntake(farm::dds::Bus& bus, const std::string& experiment)
    : experiment_(experiment),
      // Each reader refuses samples larger than any experiment allows before taking memory for them.
      spec_in_(bus, farm::dds::kSpecTopic, "latest_reader", farm::dds::kMaxSpecBytes,
               [this](eprosima::fastdds::dds::DataReader* r) {
                 SpecIn in;
                 eprosima::fastdds::dds::SampleInfo info;
                 while (decltype(spec_in_)::take_from(r, in.spec, info)) {
                   in.writer = info.sample_identity.writer_guid();
                   std::lock_guard<std::mutex> lk(mu_);
                   if (specs_.size() >= kMaxSpecsIn) specs_.pop_front();
                   specs_.push_back(in);
                 }
               }),
      weights_in_(bus, farm::dds::kWeightsTopic, "latest_reader", farm::dds::kMaxPolicyBytes,
                  [this](eprosima::fastdds::dds::DataReader* r) {
                    farm::msg::PolicyWeights w;
                    while (decltype(weights_in_)::take_from(r, w)) {
                      std::lock_guard<std::mutex> lk(mu_);
                      if (weights_.size() >= kMaxExperimentsKept && !weights_.count(w.experiment_id())) {
                        // Bounded against a flood of invented experiments; the bound one is kept.
                        auto victim = weights_.begin();
                        if (victim->first == experiment_) ++victim;
                        weights_.erase(victim);
                      }
                      weights_[w.experiment_id()] = std::move(w);
                    }
                  }) {}

std::deque<WorkerIntake::SpecIn> WorkerIntake::take_specs() {
  std::deque<SpecIn> got;
  std::lock_guard<std::mutex> lk(mu_);
  got.swap(specs_);
  return got;
}

std::optional<farm::msg::PolicyWeights> WorkerIntake::take_weights(std::vector<std::string>* others) {
  std::lock_guard<std::mutex> lk(mu_);
  for (const auto& [id, _] : weights_)
    if (id != experiment_) others->push_back(id);
  auto it = weights_.find(experiment_);
  if (it == weights_.end()) return std::nullopt;
  farm::msg::PolicyWeights w = std::move(it->second);
  weights_.erase(it);
  return w;
}

void WorkerIntake::bind(const std::string& experiment) {
  std::lock_guard<std::mutex> lk(mu_);
  experiment_ = experiment;
}

}  // namespace farm
