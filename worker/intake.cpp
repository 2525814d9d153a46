#include "intake.h"

namespace farm {

WorkerIntake::WorkerIntake(farm::dds::Bus& bus, const std::string& experiment)
    : experiment_(experiment),
      // Each reader refuses samples larger than any experiment allows before taking memory for them.
      spec_in_(
          bus, farm::dds::kSpecTopic, "latest_reader", farm::dds::kMaxSpecBytes,
          [this](eprosima::fastdds::dds::DataReader* r) {
            SpecIn in;
            eprosima::fastdds::dds::SampleInfo info;
            while (decltype(spec_in_)::take_from(r, in.spec, info)) {
              in.writer = info.sample_identity.writer_guid();
              const size_t bytes = spec_bytes(in.spec);
              std::lock_guard<std::mutex> lk(mu_);
              while (!specs_.empty() && (specs_.size() >= kMaxSpecsIn || specs_bytes_ + bytes > kMaxSpecsInBytes)) {
                specs_bytes_ -= spec_bytes(specs_.front().spec);
                specs_.pop_front();
              }
              specs_.push_back(std::move(in));
              specs_bytes_ += bytes;
            }
          }),
      weights_in_(bus, farm::dds::kWeightsTopic, "latest_reader", farm::dds::kMaxPolicyBytes,
                  [this](eprosima::fastdds::dds::DataReader* r) {
                    farm::msg::PolicyWeights w;
                    eprosima::fastdds::dds::SampleInfo info;
                    while (decltype(weights_in_)::take_from(r, w, info)) {
                      std::lock_guard<std::mutex> lk(mu_);
                      const std::string from = farm::dds::participant_key(info.sample_identity.writer_guid());
                      if (!experiment_.empty() && w.experiment_id() == experiment_) {
                        keep_own(from, std::move(w));
                        continue;
                      }
                      if (weights_.size() >= kMaxExperimentsKept && !weights_.count(w.experiment_id()))
                        weights_.erase(weights_.begin());  // bounded against a flood of invented experiments
                      const std::string id = w.experiment_id();
                      weights_[id] = {from, std::move(w)};
                    }
                  }) {}

std::deque<WorkerIntake::SpecIn> WorkerIntake::take_specs() {
  std::deque<SpecIn> got;
  std::lock_guard<std::mutex> lk(mu_);
  got.swap(specs_);
  specs_bytes_ = 0;
  return got;
}

size_t WorkerIntake::spec_bytes(const farm::msg::ExperimentSpec& s) {
  return s.experiment_id().size() + s.config_text().size() + s.task_name().size() + 64;
}

size_t WorkerIntake::queued_spec_bytes() {
  std::lock_guard<std::mutex> lk(mu_);
  return specs_bytes_;
}

void WorkerIntake::keep_own(const std::string& participant, farm::msg::PolicyWeights&& w) {
  if (!learner_.empty() && participant != learner_) ++weights_refused_;
  if (own_.size() >= kMaxLearnersKept && !own_.count(participant)) {
    // Bounded against a flood of participants: the joined learner's are kept.
    auto victim = own_.begin();
    if (victim->first == learner_) ++victim;
    own_.erase(victim);
  }
  own_[participant] = std::move(w);
}

std::optional<farm::msg::PolicyWeights> WorkerIntake::take_weights(std::vector<std::string>* others,
                                                                   uint64_t* refused) {
  std::lock_guard<std::mutex> lk(mu_);
  *refused = weights_refused_;
  for (const auto& [id, _] : weights_) others->push_back(id);
  weights_.clear();  // other experiments': only their ids are noted
  auto it = own_.find(learner_);
  if (learner_.empty() || it == own_.end()) return std::nullopt;
  farm::msg::PolicyWeights w = std::move(it->second);
  own_.erase(it);
  return w;
}

void WorkerIntake::bind(const std::string& experiment) {
  std::lock_guard<std::mutex> lk(mu_);
  experiment_ = experiment;
  // What came before the worker knew its experiment: kept under its participant like what comes now.
  const auto it = weights_.find(experiment);
  if (it == weights_.end()) return;
  Latest latest = std::move(it->second);
  weights_.erase(it);
  keep_own(latest.participant, std::move(latest.weights));
}

void WorkerIntake::bind_learner(const eprosima::fastrtps::rtps::GUID_t& spec_writer) {
  std::lock_guard<std::mutex> lk(mu_);
  learner_ = farm::dds::participant_key(spec_writer);
}

}  // namespace farm
