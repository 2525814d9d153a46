// The worker's evaluation requests over a real DDS bus (three participants in this process: the
// worker, the learner it joined, and a stranger): a flood of the stranger's requests addressed to
// the worker pushes none of the learner's out before the worker's loop polls, and the stranger's
// are neither run nor answered.
#include <gtest/gtest.h>

#include <unistd.h>

#include <chrono>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include "evaluations.h"
#include "meter.h"
#include "task.h"

namespace {

farm::msg::EvaluationRequest request(uint64_t id, uint32_t episodes) {
  farm::msg::EvaluationRequest q;
  q.experiment_id("exp");
  q.worker_id("w1");
  q.request_id(id);
  q.episodes(episodes);
  return q;
}

TEST(WorkerEvaluations, AStrangersFloodPushesNoLearnerRequestOut) {
  farm::dds::BusOptions o;
  o.domain = 120 + int(getpid() % 80);
  farm::dds::Bus worker_bus(o, "test worker"), learner_bus(o, "test learner"), stranger_bus(o, "test stranger");
  std::vector<std::string> lines;
  std::mutex lines_mu;
  farm::Evaluations evals(worker_bus, "w1", [&](const std::string& l) {
    std::lock_guard<std::mutex> lk(lines_mu);
    lines.push_back(l);
  });
  using RequestWriter = farm::dds::Writer<farm::msg::EvaluationRequest, farm::msg::EvaluationRequestPubSubType>;
  RequestWriter learner(learner_bus, farm::dds::kEvalRequestTopic, "batch_writer"),
      stranger(stranger_bus, farm::dds::kEvalRequestTopic, "batch_writer");
  std::mutex answers_mu;
  std::vector<farm::msg::EvaluationAnswer> answers;
  farm::dds::Reader<farm::msg::EvaluationAnswer, farm::msg::EvaluationAnswerPubSubType> answers_in(
      learner_bus, farm::dds::kEvalAnswerTopic, "batch_reader", [&](eprosima::fastdds::dds::DataReader* r) {
        farm::msg::EvaluationAnswer a;
        eprosima::fastdds::dds::SampleInfo info;
        while (decltype(answers_in)::take_from(r, a, info)) {
          std::lock_guard<std::mutex> lk(answers_mu);
          answers.push_back(a);
        }
      });
  const double t0 = farm::now_seconds();
  while ((learner.matched() < 1 || stranger.matched() < 1 || answers_in.matched() < 1) && farm::now_seconds() - t0 < 10)
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  ASSERT_GE(learner.matched(), 1);
  ASSERT_GE(stranger.matched(), 1);
  ASSERT_GE(answers_in.matched(), 1);

  farm::config::TaskConfig tc;
  tc.set_name("pendulum");
  const farm::Evaluations::Joined joined{"exp", farm::robots::make_task(tc), 10, 42,
                                         farm::dds::participant_key(learner_bus.participant()->guid())};
  evals.poll(joined);  // the worker's loop polls from its join on

  // Between two polls: the learner asks once (0 episodes: refused and answered at once, so the test
  // needs no policy), and the stranger sends far more requests than the queue holds.
  auto ask = request(7, 0);
  ASSERT_TRUE(learner.write(ask));
  for (uint64_t k = 0; k < 40; ++k) {
    auto forged = request(1000 + k, 0);
    ASSERT_TRUE(stranger.write(forged));
  }
  ASSERT_TRUE(learner.wait_for_acks(5));
  ASSERT_TRUE(stranger.wait_for_acks(5));
  evals.poll(joined);

  const double t1 = farm::now_seconds();
  while (farm::now_seconds() - t1 < 5) {
    {
      std::lock_guard<std::mutex> lk(answers_mu);
      if (!answers.empty()) break;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(300));  // any further answer
  std::lock_guard<std::mutex> lk(answers_mu);
  ASSERT_EQ(answers.size(), 1u) << "the learner's request was pushed out, or a stranger's was answered";
  EXPECT_EQ(answers[0].request_id(), 7u);
  EXPECT_EQ(answers[0].worker_session(), 42u);
  EXPECT_NE(answers[0].error().find("episodes 0 outside 1..10"), std::string::npos) << answers[0].error();
}

}  // namespace
