// The worker's intake of ExperimentSpecs and PolicyWeights. Both are taken on Fast DDS's listener
// thread as they arrive: the readers keep one sample for all learners together, so with two
// experiments on the domain the other one's next write would otherwise replace this worker's
// before the collect loop takes it. Specs are kept in order (the first experiment seen binds an
// unbound worker), weights the latest per experiment; both bounded.
#pragma once

#include <cstdint>
#include <deque>
#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "dds.h"
#include "farm.h"
#include "farmPubSubTypes.h"

namespace farm {

class WorkerIntake {
 public:
  // A spec as it arrived, with the writer that sent it.
  struct SpecIn {
    farm::msg::ExperimentSpec spec;
    eprosima::fastrtps::rtps::GUID_t writer;
  };
  // experiment: the one this worker serves ("" until it binds).
  WorkerIntake(farm::dds::Bus& bus, const std::string& experiment);

  // The specs that arrived since the last call, oldest first.
  std::deque<SpecIn> take_specs();
  // What the specs not yet taken hold (their strings), at most kMaxSpecsInBytes.
  size_t queued_spec_bytes();
  // Specs kept between two take_specs(): at most kMaxSpecsIn, and at most kMaxSpecsInBytes of their
  // strings, oldest out first. A learner's spec is a few kilobytes and comes again every
  // dds::kSpecRepublishSeconds; a participant that sends specs just under the reader's bound
  // (dds::kMaxSpecBytes) as fast as the network goes holds two of them, not kMaxSpecsIn.
  static constexpr size_t kMaxSpecsIn = 256, kMaxSpecsInBytes = 2 * size_t(farm::dds::kMaxSpecBytes);
  // The latest weights of the bound experiment from its learner (bind_learner), if new ones came;
  // the ids of other experiments whose weights came go to *others, and *refused is how many of the
  // experiment's weights came from another participant than its learner so far.
  std::optional<farm::msg::PolicyWeights> take_weights(std::vector<std::string>* others, uint64_t* refused);
  // Binds the worker to its experiment: its weights are kept under a flood of invented ones.
  void bind(const std::string& experiment);
  // The learner that speaks for the experiment, by the writer of the spec the worker joined (or the
  // restarted learner's): weights are taken from that participant alone. Another's latest are kept
  // apart (a few participants at most), so a restarted learner's weights, come before its spec is
  // believed, are there when it is.
  void bind_learner(const eprosima::fastrtps::rtps::GUID_t& spec_writer);
  bool spec_writer_matched(const eprosima::fastrtps::rtps::GUID_t& writer) { return spec_in_.writer_matched(writer); }
  void wait_for_spec(double seconds) { spec_in_.wait(seconds); }
  void wait_for_weights(double seconds) { weights_in_.wait(seconds); }

 private:
  // Weights of up to 64 MiB each (dds::kMaxPolicyBytes): the experiment's learner's and one other's
  // (a restarted learner's, or an impostor's), and the latest of a few other experiments.
  static constexpr size_t kMaxExperimentsKept = 8, kMaxLearnersKept = 2;
  static size_t spec_bytes(const farm::msg::ExperimentSpec& s);
  struct Latest {
    std::string participant;
    farm::msg::PolicyWeights weights;
  };
  void keep_own(const std::string& participant, farm::msg::PolicyWeights&& w);
  std::mutex mu_;
  std::string experiment_;
  std::string learner_;                                  // participant key of the bound learner ("" until joined)
  std::map<std::string, farm::msg::PolicyWeights> own_;  // the experiment's latest, per participant
  uint64_t weights_refused_ = 0;
  std::deque<SpecIn> specs_;               // bounded: kMaxSpecsIn, kMaxSpecsInBytes
  size_t specs_bytes_ = 0;                 // spec_bytes() over specs_
  std::map<std::string, Latest> weights_;  // of other experiments; bounded: kMaxExperimentsKept
  farm::dds::Reader<farm::msg::ExperimentSpec, farm::msg::ExperimentSpecPubSubType> spec_in_;
  farm::dds::Reader<farm::msg::PolicyWeights, farm::msg::PolicyWeightsPubSubType> weights_in_;
};

}  // namespace farm
