// The learner's checks of an EvaluationAnswer (learner/eval_answer.h): a well-formed answer passes,
// and each way an answer can be wrong (another experiment, learner, request, worker, session or
// version; an error; the wrong number of episodes or metrics; a length past the time limit; a NaN)
// is refused with a reason naming it. The size bound covers the largest good answer.
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <string>
#include <vector>

#include "eval_answer.h"

namespace farm {
namespace {

EvalExpected expected() {
  EvalExpected e;
  e.experiment_id = "exp";
  e.worker_id = "w1";
  e.learner_session = 7;
  e.request_id = 42;
  e.worker_session = 9;
  e.policy_version = 3;
  e.episodes = 3;
  e.num_metrics = 2;
  e.max_episode_steps = 200;
  return e;
}

farm::msg::EvaluationAnswer good() {
  farm::msg::EvaluationAnswer a;
  a.experiment_id("exp");
  a.worker_id("w1");
  a.learner_session(7);
  a.request_id(42);
  a.worker_session(9);
  a.policy_version(3);
  a.seconds(0.5);
  std::vector<farm::msg::EvaluationEpisode> eps(3);
  for (auto& e : eps) {
    e.episode_return(-150.f);
    e.length(200);
    e.metrics({0.5f, 1.f});
  }
  a.episodes(eps);
  return a;
}

TEST(EvalAnswer, AWellFormedAnswerPasses) { EXPECT_EQ(check_eval_answer(good(), expected()), ""); }

TEST(EvalAnswer, EachWrongFieldIsRefusedByName) {
  const std::vector<std::pair<std::string, std::function<void(farm::msg::EvaluationAnswer&)>>> cases = {
      {"experiment", [](auto& a) { a.experiment_id("other"); }},
      {"learner session", [](auto& a) { a.learner_session(8); }},
      {"request", [](auto& a) { a.request_id(41); }},
      {"from worker", [](auto& a) { a.worker_id("w2"); }},
      {"worker session", [](auto& a) { a.worker_session(10); }},
      {"policy v", [](auto& a) { a.policy_version(4); }},
      {"could not evaluate", [](auto& a) { a.error("bad policy"); }},
      {"error text", [](auto& a) { a.error(std::string(farm::dds::kMaxEvalTextBytes + 1, 'x')); }},
      {"episodes, asked", [](auto& a) { a.episodes().pop_back(); }},
      {"seconds", [](auto& a) { a.seconds(NAN); }},
      {"return is not finite", [](auto& a) { a.episodes()[1].episode_return(INFINITY); }},
      {"length 201", [](auto& a) { a.episodes()[2].length(201); }},
      {"length 0", [](auto& a) { a.episodes()[0].length(0); }},
      {"metrics, the task has", [](auto& a) { a.episodes()[0].metrics({1.f}); }},
      {"metric 1 is not finite",
       [](auto& a) {
         a.episodes()[0].metrics({1.f, NAN});
       }},
  };
  for (const auto& [what, spoil] : cases) {
    auto a = good();
    spoil(a);
    const std::string why = check_eval_answer(a, expected());
    EXPECT_NE(why.find(what), std::string::npos) << "expected a reason naming '" << what << "', got '" << why << "'";
  }
}

TEST(EvalAnswer, TheSizeBoundHoldsTheLargestGoodAnswer) {
  EvalExpected e = expected();
  e.episodes = 1000;
  e.num_metrics = 6;
  auto a = good();
  std::vector<farm::msg::EvaluationEpisode> eps(1000);
  for (auto& ep : eps) {
    ep.length(1);
    ep.metrics(std::vector<float>(6, 1.f));
  }
  a.episodes(eps);
  a.worker_id(std::string(farm::dds::kMaxEvalTextBytes, 'w'));
  e.worker_id = a.worker_id();
  ASSERT_EQ(check_eval_answer(a, e), "");
  farm::msg::EvaluationAnswerPubSubType type;
  const uint32_t size = type.getSerializedSizeProvider(&a)();
  EXPECT_LE(size, max_eval_answer_bytes(a.experiment_id().size(), 1000, 6));
  EXPECT_GT(size, max_eval_answer_bytes(a.experiment_id().size(), 500, 6)) << "the bound is far too loose";
}

}  // namespace
// A return no episode of the task can reach (beyond length x the spec's reward_bound) is refused;
// one at the bound passes; with no declared bound only finiteness is asked.
TEST(EvalAnswer, ReturnBeyondTheTasksRewardBoundIsRefused) {
  EvalExpected e = expected();
  e.reward_bound = 16.3;
  auto a = good();
  a.episodes()[1].episode_return(1e30f);
  a.episodes()[1].length(1);
  const std::string why = check_eval_answer(a, e);
  EXPECT_NE(why.find("episode 1: return"), std::string::npos) << why;
  EXPECT_NE(why.find("beyond what 1 steps of this task can give"), std::string::npos) << why;
  a.episodes()[1].episode_return(-16.3f * 200);
  a.episodes()[1].length(200);
  EXPECT_EQ(check_eval_answer(a, e), "");
  a.episodes()[1].episode_return(-16.3f * 201);
  EXPECT_NE(check_eval_answer(a, e), "");
  e.reward_bound = HUGE_VAL;
  EXPECT_EQ(check_eval_answer(a, e), "");
}

// A task whose reward is never positive (the pendulum's cost): a positive return is refused however
// long the episode, where the two-sided bound let 1,412 through; 0 and below pass.
TEST(EvalAnswer, ReturnAboveAOneSidedBoundIsRefused) {
  EvalExpected e = expected();
  e.reward_bound = 16.3;
  e.reward_max = 0;
  auto a = good();
  a.episodes()[0].episode_return(1412.f);
  a.episodes()[0].length(200);
  const std::string why = check_eval_answer(a, e);
  EXPECT_NE(why.find("episode 0: return"), std::string::npos) << why;
  a.episodes()[0].episode_return(0.f);
  EXPECT_EQ(check_eval_answer(a, e), "");
  // Rewards in [0, 1] (cart-pole): a negative return is refused.
  e.reward_max = HUGE_VAL;
  e.reward_min = 0;
  a.episodes()[0].episode_return(-0.5f);
  EXPECT_NE(check_eval_answer(a, e), "");
}

// Parts of one evaluation from several workers: honest parts agree; a part whose mean is far from
// the other's is refused however wide its own spread (a forger with four episodes at 3,251 and one
// at -1,505 against an honest pendulum near -150 made the old combined-error rule agree); one worker
// alone never confirms.
TEST(EvalAnswer, ReturnsAgreeOnlyWithinTheNarrowerSidesError) {
  using V = Agreement::Verdict;
  const std::vector<double> honest_a{-140, -160, -150, -145, -155}, honest_b{-152, -148, -139, -161, -150};
  EXPECT_EQ(returns_agree({{"w1", honest_a}, {"w2", honest_b}}, 4.0, 0.05).verdict, V::Agree);
  const std::vector<double> forged{3251, 3251, 3251, 3251, -1505};
  const Agreement forged_part = returns_agree({{"w1", honest_a}, {"w2", forged}}, 4.0, 0.05);
  EXPECT_EQ(forged_part.verdict, V::Disagree) << forged_part.why;
  // Widening the spread further changes nothing.
  const std::vector<double> wider{1e6, 1e6, 1e6, 1e6, -4e6 + 2000};
  EXPECT_EQ(returns_agree({{"w1", honest_a}, {"w2", wider}}, 4.0, 0.05).verdict, V::Disagree);
  // A third, honest worker does not carry a forged part through.
  EXPECT_EQ(returns_agree({{"w1", honest_a}, {"w2", forged}, {"w3", honest_b}}, 4.0, 0.05).verdict, V::Disagree);
  EXPECT_EQ(returns_agree({{"w1", honest_a}}, 4.0, 0.05).verdict, V::OneWorker);
  EXPECT_EQ(returns_agree({}, 4.0, 0.05).verdict, V::OneWorker);
  // Deterministic parts that tie agree; a NaN never does.
  EXPECT_EQ(returns_agree({{"w1", {-100, -100}}, {"w2", {-100}}}, 4.0, 0.05).verdict, V::Agree);
  EXPECT_EQ(returns_agree({{"w1", {NAN}}, {"w2", {-100}}}, 4.0, 0.05).verdict, V::Disagree);
}

}  // namespace farm
