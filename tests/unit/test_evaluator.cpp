// The learner's evaluations (learner/evaluator.h) over a channel of the test's own: no process, no
// DDS participant. An evaluation split over the ready workers, its parts merged into one report, a
// part lost with its worker asked again of another, a second loss giving the evaluation up,
// answers from a participant not asked refused, two disagreeing workers under security, and the
// networks as they were when asked kept as the best (learner/checkpointer.h).
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <deque>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "checkpoint.h"
#include "checkpointer.h"
#include "evaluator.h"
#include "events.h"

namespace farm {
namespace {

namespace fs = std::filesystem;

// Requests are kept as written; answers are handed out in the order the test queues them.
class FakeChannel : public EvalChannel {
 public:
  std::vector<msg::EvaluationRequest> sent;
  std::deque<std::pair<msg::EvaluationAnswer, Writer>> answers;
  bool secure = false;

  bool write(msg::EvaluationRequest& request) override {
    sent.push_back(request);
    return true;
  }
  bool take(msg::EvaluationAnswer& answer, Writer& writer) override {
    if (answers.empty()) return false;
    answer = answers.front().first;
    writer = answers.front().second;
    answers.pop_front();
    return true;
  }
  bool matched() const override { return true; }
  void wait(double) override {}
  bool secured() const override { return secure; }

  // The answer of the worker asked, from its own participant: one episode of 10 steps per return,
  // its metric a tenth of the return.
  void answer(const msg::EvaluationRequest& q, const std::vector<float>& returns) {
    answer_from(q, returns, {"participant-" + q.worker_id(), q.worker_id()});
  }
  void answer_from(const msg::EvaluationRequest& q, const std::vector<float>& returns, const Writer& writer) {
    msg::EvaluationAnswer a;
    a.experiment_id(q.experiment_id());
    a.learner_session(q.learner_session());
    a.request_id(q.request_id());
    a.worker_id(q.worker_id());
    a.worker_session(1);
    a.policy_version(q.policy_version());
    std::vector<msg::EvaluationEpisode> episodes;
    for (float r : returns) {
      msg::EvaluationEpisode e;
      e.episode_return(r);
      e.length(10);
      e.metrics({r / 10});
      episodes.push_back(e);
    }
    a.episodes(episodes);
    a.seconds(0.5);
    answers.emplace_back(a, writer);
  }
};

RosterThread::Worker worker(const std::string& id, int envs = 4) {
  RosterThread::Worker w;
  w.key = id + "#1";
  w.view.last.worker_id(id);
  w.view.last.worker_session(1);
  w.view.last.envs(uint32_t(envs));
  w.view.last.state("running");
  w.view.writer = "participant-" + id;
  w.live = true;
  return w;
}

PolicyParams policy(uint64_t version) {
  PolicyParams p;
  p.version = version;
  p.head = PolicyHead::kGaussian;
  p.layout.sizes = {3, 4, 1};
  p.layout.activation = Activation::kTanh;
  p.params.assign(p.layout.num_params(), 0.1f);
  p.log_std = {-1.f};
  return p;
}

EvalAsk ask_of(uint64_t version, int episodes, const std::string& label = "eval") {
  EvalAsk a;
  a.label = label;
  a.episodes = episodes;
  a.version = version;
  a.updates = int64_t(version) * 10;
  a.elapsed = double(version);
  return a;
}

class EvaluatorTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("farm_evaluator_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::create_directories(dir_);
    cfg_.set_experiment_id("ev");
    cfg_.mutable_eval()->set_episodes(5);
    cfg_.mutable_eval()->set_final_episodes(5);
    cfg_.mutable_eval()->set_min_episodes_per_worker(2);
    cfg_.mutable_eval()->set_answer_timeout_seconds(600);
    spec_.metric_names = {"speed"};
    spec_.max_episode_steps = 100;
    events_.open((dir_ / "events.jsonl").string());
  }
  void TearDown() override { fs::remove_all(dir_); }

  void start() {
    auto channel = std::make_unique<FakeChannel>();
    bus_ = channel.get();
    evaluator_ = std::make_unique<Evaluator>(
        std::move(channel), cfg_, spec_, [this] { return workers_; }, events_,
        [this](const std::string& m) { log_ += m + "\n"; }, (dir_ / "evaluating").string());
  }
  // Asks an evaluation of policy `version`, its networks a file that names the version.
  bool ask(uint64_t version, int episodes) {
    return evaluator_->ask(policy(version), ask_of(version, episodes), [version](const std::string& folder) {
      std::ofstream(folder + "/networks.txt") << "v" << version;
    });
  }
  int events_of(const std::string& kind) {
    std::ifstream in(dir_ / "events.jsonl");
    int n = 0;
    for (std::string line; std::getline(in, line);) n += nlohmann::json::parse(line)["event"] == kind;
    return n;
  }

  fs::path dir_;
  config::ExperimentConfig cfg_;
  robots::TaskSpec spec_;
  EventLog events_;
  std::vector<RosterThread::Worker> workers_;
  FakeChannel* bus_ = nullptr;
  std::unique_ptr<Evaluator> evaluator_;
  std::string log_;
};

TEST_F(EvaluatorTest, SplitsAnEvaluationOverTheReadyWorkersAndMergesTheParts) {
  workers_ = {worker("a"), worker("b"), worker("c", 0)};  // c has not built its environments
  start();
  ASSERT_TRUE(ask(1, 5));
  ASSERT_EQ(bus_->sent.size(), 2u);
  const auto q1 = bus_->sent[0], q2 = bus_->sent[1];
  EXPECT_EQ(q1.worker_id(), "a");
  EXPECT_EQ(q2.worker_id(), "b");
  // The same episodes however many parts: one seed, consecutive episode numbers.
  EXPECT_EQ(q1.seed(), q2.seed());
  EXPECT_EQ(q1.episodes() + q2.episodes(), 5u);
  EXPECT_EQ(q1.first_episode(), 0u);
  EXPECT_EQ(q2.first_episode(), q1.episodes());
  EXPECT_EQ(q1.policy().version(), 1u);

  bus_->answer(q1, std::vector<float>(q1.episodes(), 10.f));
  EXPECT_TRUE(evaluator_->poll().empty()) << "one part is still out";
  EXPECT_EQ(evaluator_->out(), 1u);
  bus_->answer(q2, std::vector<float>(q2.episodes(), 20.f));
  const auto done = evaluator_->poll();
  ASSERT_EQ(done.size(), 1u);
  const EvalReport& r = done[0].report;
  EXPECT_FALSE(done[0].given_up);
  EXPECT_EQ(r.episodes, 5);
  EXPECT_DOUBLE_EQ(r.mean, (10.0 * q1.episodes() + 20.0 * q2.episodes()) / 5);
  EXPECT_DOUBLE_EQ(r.min, 10);
  EXPECT_DOUBLE_EQ(r.max, 20);
  ASSERT_EQ(r.metrics.size(), 1u);
  EXPECT_NEAR(r.metrics[0], r.mean / 10, 1e-6);
  EXPECT_NEAR(r.metrics_min[0], 1.0, 1e-6);
  EXPECT_EQ(done[0].ask.version, 1u);
  EXPECT_EQ(evaluator_->asked(), 2u);
  EXPECT_EQ(evaluator_->answered(), 2u);
  EXPECT_EQ(evaluator_->out(), 0u);
  EXPECT_EQ(events_of("answer"), 2);
  EXPECT_EQ(events_of("evaluation"), 1);
  Evaluator::drop_snapshot(done[0].snapshot);
}

TEST_F(EvaluatorTest, OneTrainingEvaluationOutAtATime) {
  workers_ = {worker("a")};
  start();
  ASSERT_TRUE(ask(1, 2));
  EXPECT_FALSE(ask(2, 2)) << "the one of v1 is still out";
  EXPECT_EQ(bus_->sent.size(), 1u);
  EXPECT_TRUE(evaluator_->ask(policy(3), ask_of(3, 2, "final"), [](const std::string&) {}))
      << "a final evaluation is always asked";
}

TEST_F(EvaluatorTest, APartWhoseWorkerDiesIsAskedAgainOfAnother) {
  cfg_.mutable_eval()->set_min_episodes_per_worker(0);  // one part
  workers_ = {worker("a"), worker("b")};
  start();
  ASSERT_TRUE(ask(1, 3));
  ASSERT_EQ(bus_->sent.size(), 1u);
  const auto first = bus_->sent[0];
  EXPECT_EQ(first.worker_id(), "a");

  workers_[0].live = false;
  EXPECT_TRUE(evaluator_->poll().empty());
  EXPECT_EQ(evaluator_->lost(), 1u);
  ASSERT_EQ(bus_->sent.size(), 2u);
  const auto retry = bus_->sent[1];
  EXPECT_EQ(retry.worker_id(), "b");
  EXPECT_NE(retry.request_id(), first.request_id());
  EXPECT_EQ(retry.seed(), first.seed());
  EXPECT_EQ(retry.episodes(), first.episodes());
  EXPECT_EQ(events_of("eval_lost"), 1);

  bus_->answer(first, {1.f, 1.f, 1.f});  // the lost request's answer, late: not used
  bus_->answer(retry, {5.f, 6.f, 7.f});
  const auto done = evaluator_->poll();
  ASSERT_EQ(done.size(), 1u);
  EXPECT_FALSE(done[0].given_up);
  EXPECT_DOUBLE_EQ(done[0].report.mean, 6.0);
  EXPECT_EQ(evaluator_->answered(), 1u);
  EXPECT_EQ(evaluator_->invalid(), 0u);
  EXPECT_NE(evaluator_->summary().find("late 1"), std::string::npos) << evaluator_->summary();
  Evaluator::drop_snapshot(done[0].snapshot);
}

TEST_F(EvaluatorTest, APartLostTwiceGivesItsEvaluationUp) {
  workers_ = {worker("a"), worker("b")};
  start();
  ASSERT_TRUE(ask(1, 4));  // two parts
  ASSERT_EQ(bus_->sent.size(), 2u);
  bus_->answer(bus_->sent[1], {3.f, 3.f});  // b answers its part
  EXPECT_TRUE(evaluator_->poll().empty());
  workers_[0].live = false;  // a's part is lost, asked again of b
  EXPECT_TRUE(evaluator_->poll().empty());
  ASSERT_EQ(bus_->sent.size(), 3u);
  EXPECT_EQ(bus_->sent[2].worker_id(), "b");
  workers_[1].live = false;  // and lost again
  const auto done = evaluator_->poll();
  ASSERT_EQ(done.size(), 1u);
  EXPECT_TRUE(done[0].given_up);
  EXPECT_EQ(done[0].report.episodes, 0);
  EXPECT_EQ(evaluator_->lost(), 2u);
  EXPECT_EQ(evaluator_->out(), 0u);
  Evaluator::drop_snapshot(done[0].snapshot);
}

TEST_F(EvaluatorTest, AnAnswerFromAParticipantNotAskedIsRefused) {
  cfg_.mutable_eval()->set_min_episodes_per_worker(0);
  workers_ = {worker("a")};
  start();
  ASSERT_TRUE(ask(1, 2));
  const auto q = bus_->sent.at(0);
  bus_->answer_from(q, {100.f, 100.f}, {"participant-intruder", ""});
  EXPECT_TRUE(evaluator_->poll().empty());
  EXPECT_EQ(evaluator_->invalid(), 1u);
  EXPECT_EQ(evaluator_->out(), 1u) << "the request stays out for the worker asked";
  bus_->answer(q, {2.f, 4.f});
  const auto done = evaluator_->poll();
  ASSERT_EQ(done.size(), 1u);
  EXPECT_DOUBLE_EQ(done[0].report.mean, 3.0);
  Evaluator::drop_snapshot(done[0].snapshot);
}

TEST_F(EvaluatorTest, UnderSecurityTwoWorkersThatDisagreeConfirmNothing) {
  cfg_.mutable_eval()->set_min_episodes_per_worker(8);  // one part by the size alone
  workers_ = {worker("a"), worker("b")};
  start();
  bus_->secure = true;
  ASSERT_TRUE(ask(1, 8));
  ASSERT_EQ(bus_->sent.size(), 2u) << "two workers at least under security";
  bus_->answer(bus_->sent[0], {10.f, 10.5f, 9.5f, 10.f});
  bus_->answer(bus_->sent[1], {500.f, 501.f, 499.f, 500.f});
  auto done = evaluator_->poll();
  ASSERT_EQ(done.size(), 1u);
  EXPECT_FALSE(done[0].report.confirmed);
  Evaluator::drop_snapshot(done[0].snapshot);

  ASSERT_TRUE(ask(2, 8));
  ASSERT_EQ(bus_->sent.size(), 4u);
  bus_->answer(bus_->sent[2], {10.f, 10.5f, 9.5f, 10.f});
  bus_->answer(bus_->sent[3], {10.2f, 9.8f, 10.f, 10.1f});
  done = evaluator_->poll();
  ASSERT_EQ(done.size(), 1u);
  EXPECT_TRUE(done[0].report.confirmed);
  Evaluator::drop_snapshot(done[0].snapshot);
}

// The best is the networks of the version asked, kept aside when it was asked: a later, worse
// evaluation leaves them in RUN/best.
TEST_F(EvaluatorTest, TheBestKeptIsTheNetworksAsAsked) {
  cfg_.mutable_eval()->set_min_episodes_per_worker(0);
  workers_ = {worker("a")};
  start();
  Checkpointer keeper(cfg_, spec_, dir_.string(), events_, [](const std::string&) {});
  const auto manifest = [] {
    config::CheckpointManifest m;
    m.set_experiment_id("ev");
    return m;
  };
  const auto evaluate = [&](uint64_t version, float mean) {
    EXPECT_TRUE(ask(version, 5));
    bus_->answer(bus_->sent.back(), std::vector<float>(5, mean));
    auto done = evaluator_->poll();
    EXPECT_EQ(done.size(), 1u);
    if (done.empty()) return;
    EXPECT_TRUE(fs::exists(fs::path(done[0].snapshot) / "networks.txt"));
    keeper.offer(done[0].report, version, int64_t(version), 1.0, &done[0].snapshot, manifest);
    Evaluator::drop_snapshot(done[0].snapshot);
    EXPECT_FALSE(fs::exists(done[0].snapshot));
  };
  const auto best = [&] {
    std::ifstream in(fs::path(usable_checkpoint(keeper.best_dir())) / "networks.txt");
    std::stringstream s;
    s << in.rdbuf();
    return s.str();
  };
  evaluate(1, 10.f);
  EXPECT_EQ(best(), "v1");
  evaluate(2, 30.f);
  EXPECT_EQ(best(), "v2");
  EXPECT_DOUBLE_EQ(keeper.best(), 30.0);
  evaluate(3, 20.f);
  EXPECT_EQ(best(), "v2");
}

}  // namespace
}  // namespace farm
