// The worker's intake of specs and weights over a real DDS bus (participants in this process: the
// worker, the learner it joins, and a stranger): a stranger's large specs hold a bounded amount of
// memory between two polls of the worker's loop, and a learner's weights displaced by a stranger's
// before the worker joined come again.
#include <gtest/gtest.h>

#include <unistd.h>

#include <chrono>
#include <string>
#include <thread>

#include "../wait_until.h"
#include "intake.h"
#include "meter.h"
#include "mlp.h"
#include "weight_publisher.h"

namespace {

using SpecWriter = farm::dds::Writer<farm::msg::ExperimentSpec, farm::msg::ExperimentSpecPubSubType>;
using WeightsWriter = farm::dds::Writer<farm::msg::PolicyWeights, farm::msg::PolicyWeightsPubSubType>;

farm::dds::BusOptions domain(int offset) {
  farm::dds::BusOptions o;
  o.domain = 120 + int((getpid() + offset) % 80);
  return o;
}

using farm::testing::wait_until;

// Whether writer w has matched a reader within 10 s.
template <class W>
bool matched(const W& w) {
  return wait_until([&] { return w.matched() >= 1; }, 10, 50);
}

farm::PolicyParams tiny_policy(uint64_t version) {
  farm::PolicyParams p;
  p.version = version;
  p.layout = {{2, 2}, farm::Activation::kRelu};
  p.params.assign(p.layout.num_params(), 0.5f);
  return p;
}

}  // namespace

// Specs of 40-44 MiB, one after another: the worker's loop takes none of them meanwhile (a
// collect pass of seconds), and at most kMaxSpecsInBytes of them are held; the latest is among
// them. Before, up to 256 were kept whatever their size: 18 GiB at the reader's bound.
TEST(WorkerIntake, AStrangersLargeSpecsHoldBoundedMemory) {
  farm::dds::Bus worker_bus(domain(0), "test worker"), stranger_bus(domain(0), "test stranger");
  farm::WorkerIntake intake(worker_bus, "");
  SpecWriter stranger(stranger_bus, farm::dds::kSpecTopic, "latest_writer");
  ASSERT_TRUE(matched(stranger));
  farm::msg::ExperimentSpec s;
  s.experiment_id("big");
  for (int k = 0; k < 5; ++k) {
    // Sizes that differ, so that one in for one out still changes what the queue holds.
    s.config_text(std::string(size_t(40 + k) << 20, char('a' + k)));
    const size_t before = intake.queued_spec_bytes();
    ASSERT_TRUE(stranger.write(s));
    // Each arrives (the queue changes) before the next is written.
    ASSERT_TRUE(wait_until([&] { return intake.queued_spec_bytes() != before; }, 30, 20))
        << "spec " << k << " never arrived";
    EXPECT_LE(intake.queued_spec_bytes(), farm::WorkerIntake::kMaxSpecsInBytes) << "after spec " << k;
  }
  const auto got = intake.take_specs();
  ASSERT_FALSE(got.empty());
  EXPECT_EQ(got.back().spec.config_text()[0], 'e');
  EXPECT_EQ(intake.queued_spec_bytes(), 0u);
}

// Before the worker joins, a stranger writes the experiment's weights after its learner did: the
// worker's intake keeps the stranger's, and once the worker joins that learner it has none of
// its learner's. The learner writes its latest again after kWeightsRepublishSeconds without a new
// version, and the worker takes them. Before, a single-worker run waited for weights for good.
TEST(WorkerIntake, ALearnersWeightsDisplacedBeforeTheJoinComeAgain) {
  farm::dds::Bus worker_bus(domain(1), "test worker"), learner_bus(domain(1), "test learner"),
      stranger_bus(domain(1), "test stranger");
  farm::WorkerIntake intake(worker_bus, "");
  farm::WeightPublisher learner(learner_bus, "exp");
  WeightsWriter stranger(stranger_bus, farm::dds::kWeightsTopic, "latest_writer");
  ASSERT_TRUE(matched(stranger));
  // The learner's writer matches the worker's reader as the stranger's does.
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  learner.publish(tiny_policy(1), 0);
  std::this_thread::sleep_for(std::chrono::seconds(1));
  farm::msg::PolicyWeights forged;
  farm::dds::to_wire(tiny_policy(999), "exp", forged);
  ASSERT_TRUE(stranger.write(forged));
  ASSERT_TRUE(stranger.wait_for_acks(5));
  std::this_thread::sleep_for(std::chrono::milliseconds(500));

  intake.bind("exp");
  eprosima::fastrtps::rtps::GUID_t spec_writer;
  spec_writer.guidPrefix = learner_bus.participant()->guid().guidPrefix;
  intake.bind_learner(spec_writer);
  std::vector<std::string> others;
  uint64_t refused = 0;
  EXPECT_FALSE(intake.take_weights(&others, &refused)) << "the learner's weights were not displaced: nothing to show";

  learner.republish_if_due(farm::now_seconds());  // not due yet: nothing written
  std::this_thread::sleep_for(std::chrono::seconds(1));
  EXPECT_FALSE(intake.take_weights(&others, &refused));
  learner.republish_if_due(farm::now_seconds() + farm::dds::kWeightsRepublishSeconds);
  std::optional<farm::msg::PolicyWeights> got;
  EXPECT_TRUE(wait_until([&] { return bool(got = intake.take_weights(&others, &refused)); }, 10, 20));
  ASSERT_TRUE(got);
  EXPECT_EQ(got->version(), 1u);
}
