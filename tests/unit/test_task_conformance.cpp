// Every registered task against the Task interface (robots/task.h), in the manner of EnvPool's
// determinism test over all its registered environments: the suite is instantiated over
// task_names(), so a robot added to the registry is checked with no edit here. Each task is built
// from a TaskConfig that names it and sets nothing else (the config defaults), plus the option
// variants listed in variant_cases() that change the action space. The task of terms ("terms") has
// no default model: it is checked with every shipped config of it in deploy/configs/ instead.
//
// What is checked, per task:
//   - the same seed gives bit-identical observations, rewards and ends, across two Task instances
//     and across states of one instance stepped in turn; a state reused after an episode behaves
//     as a fresh one; a different seed gives a different episode;
//   - observations are exactly obs_dim finite floats and metrics exactly metric_names.size()
//     finite floats (nothing is written past either); rewards are finite;
//   - an episode ends by truncation exactly at max_episode_steps, terminations come no later;
//     state.step and state.episode_return count what the worker reports (worker/vec_env.cpp);
//   - continuous actions outside [-1, 1] act as the nearest bound and NaN as 0; discrete indices
//     outside [0, num_actions) are refused with std::invalid_argument, the state left as it was.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <ostream>
#include <random>
#include <regex>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

#include "config.h"
#include "task.h"
#include "task_specs.h"

namespace farm::robots {
namespace {

struct TaskCase {
  std::string label;  // the test name's suffix
  config::TaskConfig config;
};

void PrintTo(const TaskCase& c, std::ostream* os) { *os << c.label; }

std::vector<TaskCase> default_cases() {
  std::vector<TaskCase> cases;
  for (const auto& name : task_names()) {
    if (name == "terms") continue;  // terms_cases()
    TaskCase c{name, {}};
    c.config.set_name(name);
    cases.push_back(c);
  }
  return cases;
}

// Options that switch a task's action space: the defaults above cover one side only.
std::vector<TaskCase> variant_cases() {
  TaskCase jetbot{"jetbot_continuous", {}}, kaya{"kaya_continuous", {}};
  jetbot.config.set_name("jetbot");
  jetbot.config.mutable_jetbot()->mutable_scene()->set_discrete_actions(false);
  kaya.config.set_name("kaya");
  kaya.config.mutable_kaya()->mutable_scene()->set_discrete_actions(false);
  return {jetbot, kaya};
}

// Every shipped config of the task of terms, loaded as the learner loads it (its model read into it).
std::vector<TaskCase> terms_cases() {
  std::vector<TaskCase> cases;
  for (const auto& e : std::filesystem::directory_iterator(std::string(FARM_SOURCE_DIR) + "/deploy/configs")) {
    if (e.path().extension() != ".txtpb") continue;
    const auto cfg = load_config_file(e.path().string());
    if (cfg.task().name() == "terms") cases.push_back({"terms_" + e.path().stem().string(), cfg.task()});
  }
  std::sort(cases.begin(), cases.end(), [](const TaskCase& a, const TaskCase& b) { return a.label < b.label; });
  return cases;
}

// Entries past the end of every output buffer; they must keep the sentinel.
constexpr int kPad = 16;

// A quiet NaN with a payload of its own, so an entry a task leaves unwritten fails the finiteness
// check and one written past the end shows as a changed bit pattern.
float sentinel() {
  const uint32_t bits = 0x7fc0beefu;
  float f;
  std::memcpy(&f, &bits, sizeof f);
  return f;
}

bool same_bits(const std::vector<float>& a, const std::vector<float>& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(float)) == 0;
}

// One step as seen from outside: what the worker forwards to the learner.
struct Outcome {
  std::vector<float> obs;
  float reward = 0.f;
  bool terminated = false, truncated = false;
  bool ended() const { return terminated || truncated; }
};

bool same(const Outcome& a, const Outcome& b) {
  return same_bits(a.obs, b.obs) && std::memcmp(&a.reward, &b.reward, sizeof(float)) == 0 &&
         a.terminated == b.terminated && a.truncated == b.truncated;
}

std::string describe(const std::vector<float>& v) {
  std::string s;
  for (float x : v) s += (s.empty() ? "" : " ") + std::to_string(x);
  return "[" + s + "]";
}

class TaskConformance : public ::testing::TestWithParam<TaskCase> {
 protected:
  void SetUp() override {
    task_ = make_task(GetParam().config);
    spec_ = task_->spec();
    bound_ = task_spec(GetParam().config).reward_bound;
    reward_min_ = task_spec(GetParam().config).reward_min;
    reward_max_ = task_spec(GetParam().config).reward_max;
  }

  std::unique_ptr<Task> another_instance() const { return make_task(GetParam().config); }
  bool discrete() const { return spec_.num_actions > 0; }

  // Checks the sentinel-padded buffer a call wrote `n` floats into, returns those n.
  std::vector<float> checked(const std::vector<float>& buf, int n, const char* what) const {
    const auto bad = std::find_if(buf.begin(), buf.begin() + n, [](float x) { return !std::isfinite(x); });
    EXPECT_EQ(bad, buf.begin() + n) << what << " entry " << (bad - buf.begin()) << " of " << n
                                    << " is not finite: " << describe(std::vector<float>(buf.begin(), buf.begin() + n));
    const std::vector<float> tail(buf.begin() + n, buf.end());
    EXPECT_TRUE(same_bits(tail, std::vector<float>(kPad, sentinel())))
        << what << ": written past its " << n << " entries: " << describe(tail);
    return std::vector<float>(buf.begin(), buf.begin() + n);
  }

  std::vector<float> reset(TaskState& s, uint64_t seed) const {
    std::vector<float> buf(spec_.obs_dim + kPad, sentinel());
    task_->reset(s, seed, buf.data());
    EXPECT_EQ(s.step, 0);
    EXPECT_EQ(s.episode_return, 0.0);
    return checked(buf, spec_.obs_dim, "reset observation");
  }

  Outcome step(TaskState& s, const std::vector<float>& action, const Task* task = nullptr) const {
    if (!task) task = task_.get();
    std::vector<float> buf(spec_.obs_dim + kPad, sentinel());
    const StepResult r = task->step(s, action.data(), buf.data());
    EXPECT_TRUE(std::isfinite(r.reward)) << "reward " << r.reward << " at step " << s.step;
    // The bound the learner holds evaluation answers to (TaskSpec::reward_bound, from the config).
    EXPECT_LE(std::abs(double(r.reward)), bound_)
        << "reward " << r.reward << " at step " << s.step << " beyond the spec's reward_bound";
    EXPECT_GE(double(r.reward), reward_min_) << "reward below the spec's reward_min at step " << s.step;
    EXPECT_LE(double(r.reward), reward_max_) << "reward above the spec's reward_max at step " << s.step;
    return {checked(buf, spec_.obs_dim, "step observation"), r.reward, r.terminated, r.truncated};
  }

  std::vector<float> metrics(const TaskState& s) const {
    const int n = int(spec_.metric_names.size());
    std::vector<float> buf(n + kPad, sentinel());
    task_->episode_metrics(s, buf.data());
    return checked(buf, n, "episode metrics");
  }

  // A valid action: uniform in [-1, 1] per entry, or a uniform index.
  std::vector<float> random_action(std::mt19937_64& rng) const {
    if (discrete()) return {float(std::uniform_int_distribution<int>(0, spec_.num_actions - 1)(rng))};
    std::vector<float> a(spec_.act_dim);
    for (float& x : a) x = std::uniform_real_distribution<float>(-1.f, 1.f)(rng);
    return a;
  }

  std::unique_ptr<Task> task_;
  TaskSpec spec_;
  double bound_ = HUGE_VAL;                                // task_spec(config).reward_bound
  double reward_min_ = -HUGE_VAL, reward_max_ = HUGE_VAL;  // task_spec(config)'s one-sided bounds
};

TEST_P(TaskConformance, SpecIsWellFormed) {
  EXPECT_EQ(spec_.name, GetParam().config.name());
  EXPECT_NE(task_->model(), nullptr);
  EXPECT_GT(spec_.obs_dim, 0);
  EXPECT_GT(spec_.act_dim, 0);
  EXPECT_GT(spec_.max_episode_steps, 0);
  EXPECT_GE(spec_.num_actions, 0);
  if (discrete()) EXPECT_EQ(spec_.act_dim, 1) << "a discrete action is one index";
  std::set<std::string> names;
  for (const auto& n : spec_.metric_names) {
    EXPECT_FALSE(n.empty()) << "an unnamed metric";
    EXPECT_TRUE(names.insert(n).second) << "metric " << n << " twice";
  }
}

bool same_spec(const TaskSpec& a, const TaskSpec& b) {
  return a.name == b.name && a.obs_dim == b.obs_dim && a.act_dim == b.act_dim &&
         a.max_episode_steps == b.max_episode_steps && a.metric_names == b.metric_names &&
         a.num_actions == b.num_actions;
}

std::string describe(const TaskSpec& s) {
  std::string m;
  for (const auto& n : s.metric_names) m += (m.empty() ? "" : ",") + n;
  return s.name + " obs " + std::to_string(s.obs_dim) + " act " + std::to_string(s.act_dim) + " actions " +
         std::to_string(s.num_actions) + " steps " + std::to_string(s.max_episode_steps) + " metrics " + m;
}

// The learner links no MuJoCo: it sizes everything from task_spec(config), which must say what the
// built task says.
TEST_P(TaskConformance, SpecFromTheConfigAloneIsTheTasks) {
  const TaskSpec from_config = task_spec(GetParam().config);
  EXPECT_TRUE(same_spec(from_config, spec_))
      << "task_spec: " << describe(from_config) << "\ntask:      " << describe(spec_);
}

// Options that change only the observation size or the time limit.
TEST(TaskSpecFromConfig, FollowsTheOptionsThatSizeTheTask) {
  std::vector<config::TaskConfig> configs(4);
  configs[0].set_name("mclari");
  configs[0].mutable_mclari()->set_observe_gait(true);
  configs[0].mutable_mclari()->set_max_episode_steps(7);
  configs[1].set_name("mclari");
  configs[1].mutable_mclari()->set_observe_terrain(true);
  configs[2].set_name("jetbot");
  configs[2].mutable_jetbot()->mutable_scene()->set_lidar_rays(20);
  configs[3].set_name("a1");
  configs[3].mutable_a1()->set_max_episode_steps(50);
  for (const auto& c : configs) {
    const TaskSpec built = make_task(c)->spec(), from_config = task_spec(c);
    EXPECT_TRUE(same_spec(from_config, built))
        << "task_spec: " << describe(from_config) << "\ntask:      " << describe(built);
  }
  config::TaskConfig unknown;
  unknown.set_name("no_such_task");
  EXPECT_THROW(task_spec(unknown), std::invalid_argument);
}

// The two registries, MuJoCo's (make_task) and the spec side's (task_spec, the loader's checks),
// come from one list, robots/tasks.def.
TEST(TaskRegistry, BothSidesRegisterTheSameTasks) { EXPECT_EQ(registered_task_names(), task_names()); }

// Every robot's knowledge (its config section, range checks, spec) lives in its own folder under
// robots/: no code under common/ names a registered robot task. Comments are left out (a default's
// comment may cite a source paper's table column named for a robot); "terms", the task of terms,
// is no robot.
TEST(TaskRegistry, CommonNamesNoRobot) {
  std::string alternatives;
  for (const auto& n : task_names())
    if (n != "terms") alternatives += (alternatives.empty() ? "" : "|") + n;
  ASSERT_FALSE(alternatives.empty());
  const std::regex robot("(^|[^A-Za-z0-9_])(" + alternatives + ")([^A-Za-z0-9_]|$)", std::regex::icase);
  // The code of a file with its comments (// and, in CMake files, #) left out, line by line.
  const auto code_lines = [](const std::filesystem::path& p) {
    std::vector<std::string> lines;
    std::ifstream in(p);
    const bool cmake = p.filename() == "CMakeLists.txt";
    for (std::string line; std::getline(in, line);) {
      const size_t cut = line.find(cmake ? "#" : "//");
      lines.push_back(cut == std::string::npos ? line : line.substr(0, cut));
    }
    return lines;
  };
  int files = 0;
  for (const auto& e : std::filesystem::recursive_directory_iterator(std::string(FARM_SOURCE_DIR) + "/common")) {
    if (!e.is_regular_file()) continue;
    ++files;
    const auto lines = code_lines(e.path());
    for (size_t i = 0; i < lines.size(); ++i)
      EXPECT_FALSE(std::regex_search(lines[i], robot)) << e.path().string() << ":" << i + 1 << ": " << lines[i];
  }
  EXPECT_GT(files, 10);
  // The same search finds the robots where they are: their registration lines, which the task
  // section's fields are made from.
  int found = 0;
  for (const auto& line : code_lines(std::string(FARM_SOURCE_DIR) + "/robots/tasks.def"))
    found += std::regex_search(line, robot);
  EXPECT_GE(found, 8);
}

// Three states, two of one Task and one of another, reset with one seed and fed one action
// sequence in turn: a Task that kept episode data of its own, or read uninitialized memory, would
// make them diverge. After an episode, a reused state and a fresh one must agree again.
TEST_P(TaskConformance, SameSeedSameEpisode) {
  auto other = another_instance();
  auto a = task_->make_state(), b = task_->make_state(), c = other->make_state();
  uint64_t seed = 1234;
  const auto obs_a = reset(*a, seed);
  ASSERT_TRUE(same_bits(obs_a, reset(*b, seed)));
  ASSERT_TRUE(same_bits(obs_a, reset(*c, seed)));
  std::mt19937_64 rng(7);
  // 40 steps, or fewer where they cost more than a second: a step takes from a microsecond
  // (pendulum) to a simulated second at up to 75,000 physics steps (mCLARI at high frequencies).
  const auto start = std::chrono::steady_clock::now();
  for (int t = 0; t < 40 && (t < 4 || std::chrono::steady_clock::now() - start < std::chrono::seconds(1)); ++t) {
    const auto action = random_action(rng);
    const Outcome oa = step(*a, action), ob = step(*b, action), oc = step(*c, action, other.get());
    ASSERT_TRUE(same(oa, ob)) << "two states of one Task diverge at step " << t << ": " << describe(oa.obs) << " vs "
                              << describe(ob.obs);
    ASSERT_TRUE(same(oa, oc)) << "two Task instances diverge at step " << t << ": " << describe(oa.obs) << " vs "
                              << describe(oc.obs);
    ASSERT_EQ(a->step, c->step);
    ASSERT_EQ(a->episode_return, c->episode_return);
    if (oa.ended()) {
      ++seed;
      const auto first = reset(*a, seed);
      ASSERT_TRUE(same_bits(first, reset(*b, seed)));
      ASSERT_TRUE(same_bits(first, reset(*c, seed)));
    }
  }
  // `a` has run an episode; a state just made must follow it exactly from the same seed.
  auto fresh = other->make_state();
  ASSERT_TRUE(same_bits(reset(*a, 99), reset(*fresh, 99))) << "reset does not clear the last episode";
  for (int t = 0; t < 8; ++t) {
    const auto action = random_action(rng);
    const Outcome oa = step(*a, action), of = step(*fresh, action, other.get());
    ASSERT_TRUE(same(oa, of)) << "a reused state diverges from a fresh one at step " << t;
    if (oa.ended()) break;
  }
}

// Every task here draws its start (pose, noise, map, target or terrain) from the seed. A task
// whose episodes did not depend on the seed would be exempted here, with the reason.
TEST_P(TaskConformance, DifferentSeedsDifferentEpisodes) {
  auto a = task_->make_state(), b = task_->make_state();
  const auto first_a = reset(*a, 1);
  bool differ = !same_bits(first_a, reset(*b, 2));
  std::mt19937_64 rng(3);
  for (int t = 0; t < 10 && !differ; ++t) {
    const auto action = random_action(rng);
    const Outcome oa = step(*a, action), ob = step(*b, action);
    differ = !same(oa, ob);
    if (oa.ended() || ob.ended()) break;
  }
  EXPECT_TRUE(differ) << "seeds 1 and 2 gave the same episode";
}

// Runs whole episodes until one reaches the time limit, with actions that should not end it
// early: all zeros for continuous tasks (no torque, no motion, the default pose), each index in
// turn for discrete ones (a command that turns on the spot reaches the limit). Every episode,
// ended by either, has truncation exactly at max_episode_steps and termination no later.
TEST_P(TaskConformance, TruncatesExactlyAtTheTimeLimit) {
  std::vector<std::vector<float>> candidates;
  if (discrete()) {
    for (int k = 0; k < spec_.num_actions; ++k) candidates.push_back({float(k)});
  } else {
    candidates.assign(3, std::vector<float>(spec_.act_dim, 0.f));  // three seeds
  }
  const int limit = spec_.max_episode_steps;
  auto s = task_->make_state();
  bool reached = false;
  for (size_t k = 0; k < candidates.size() && !reached; ++k) {
    SCOPED_TRACE("episode " + std::to_string(k) + ", action " + describe(candidates[k]));
    reset(*s, 500 + k);
    double sum = 0;
    ASSERT_EQ(metrics(*s).size(), spec_.metric_names.size());  // no step yet: still finite
    for (int t = 1; t <= limit; ++t) {
      const Outcome o = step(*s, candidates[k]);
      sum += o.reward;
      ASSERT_EQ(s->step, t);
      ASSERT_NEAR(s->episode_return, sum, 1e-6 * std::max(1.0, std::abs(sum))) << "at step " << t;
      if (t < limit) ASSERT_FALSE(o.truncated) << "truncated at step " << t << " of " << limit;
      if (t == limit) {
        ASSERT_TRUE(o.ended()) << "step " << limit << " did not end the episode";
        reached = o.truncated;
      }
      if (t == limit / 2) metrics(*s);  // mid-episode, as a worker stopped early would ask
      if (o.ended()) break;
    }
    metrics(*s);
  }
  if (!reached && !discrete() && GetParam().config.name() == "terms") {
    // A robot that falls without torque (Gymnasium's Humanoid) ends every zero-action episode by a
    // termination term: its truncation is checked on the same config without them.
    config::TaskConfig cfg = GetParam().config;
    cfg.mutable_terms()->clear_termination();
    const auto task = make_task(cfg);
    auto u = task->make_state();
    std::vector<float> obs(spec_.obs_dim), zero(spec_.act_dim, 0.f);
    task->reset(*u, 500, obs.data());
    StepResult r;
    for (int t = 1; t <= limit && !(r.terminated || r.truncated); ++t) {
      r = task->step(*u, zero.data(), obs.data());
      ASSERT_EQ(r.truncated, t == limit) << "at step " << t;
    }
    reached = r.truncated;
  }
  EXPECT_TRUE(reached) << "no episode reached the time limit, so truncation went unchecked";
}

// Continuous actions: entries beyond [-1, 1] act as the bound (task_spec.h: the task scales an
// action in [-1, 1]), and a NaN entry as 0, which each task's step reads as no torque or force,
// standing still, the default pose or no change of gait: a diverged policy must not poison the
// simulation or the observation.
TEST_P(TaskConformance, ContinuousActionsAreClippedAndNanIsZero) {
  if (discrete()) GTEST_SKIP() << "discrete actions: see DiscreteIndicesOutOfRangeAreRefused";
  const int n = spec_.act_dim;
  std::mt19937_64 rng(11);
  std::vector<std::pair<std::vector<float>, std::vector<float>>> pairs = {
      {std::vector<float>(n, 5.f), std::vector<float>(n, 1.f)},
      {std::vector<float>(n, -7.f), std::vector<float>(n, -1.f)},
      {std::vector<float>(n, NAN), std::vector<float>(n, 0.f)},
  };
  std::vector<float> mixed(n), clipped(n);  // each entry its own way
  for (int i = 0; i < n; ++i) {
    mixed[i] = std::uniform_real_distribution<float>(-4.f, 4.f)(rng);
    if (i % 4 == 3) mixed[i] = NAN;
    clipped[i] = std::isnan(mixed[i]) ? 0.f : std::clamp(mixed[i], -1.f, 1.f);
  }
  pairs.emplace_back(mixed, clipped);
  auto out = task_->make_state(), in = task_->make_state();
  for (size_t p = 0; p < pairs.size(); ++p) {
    SCOPED_TRACE("action " + describe(pairs[p].first) + " against " + describe(pairs[p].second));
    // From a few steps into an episode, not only from the start pose.
    reset(*out, 40 + p);
    reset(*in, 40 + p);
    for (int t = 0; t < 3; ++t) {
      const auto action = random_action(rng);
      step(*out, action);
      step(*in, action);
    }
    // Twice: what the task remembers of an action (the last action observed) is the clipped one.
    for (int t = 0; t < 2; ++t) {
      const Outcome o = step(*out, pairs[p].first), i = step(*in, pairs[p].second);
      EXPECT_TRUE(same(o, i)) << describe(o.obs) << " vs " << describe(i.obs) << ", rewards " << o.reward << " vs "
                              << i.reward;
    }
  }
}

// Discrete actions: an index outside [0, num_actions), a fraction or a NaN is refused with
// std::invalid_argument (mobile_task.h, base_command) before the state is touched; every index in
// range is accepted.
TEST_P(TaskConformance, DiscreteIndicesOutOfRangeAreRefused) {
  if (!discrete()) GTEST_SKIP() << "continuous actions: see ContinuousActionsAreClippedAndNanIsZero";
  auto s = task_->make_state(), ref = task_->make_state();
  ASSERT_TRUE(same_bits(reset(*s, 8), reset(*ref, 8)));
  std::vector<float> obs(spec_.obs_dim + kPad);
  for (float bad :
       {-1.f, float(spec_.num_actions), float(spec_.num_actions) + 0.5f, 0.5f, 1e9f, -1e9f, NAN, INFINITY}) {
    EXPECT_THROW(task_->step(*s, &bad, obs.data()), std::invalid_argument) << "index " << bad;
  }
  EXPECT_EQ(s->step, 0);
  for (int k = 0; k < spec_.num_actions; ++k) {
    const std::vector<float> action = {float(k)};
    const Outcome o = step(*s, action), r = step(*ref, action);
    ASSERT_TRUE(same(o, r)) << "a refused action changed the state (index " << k << ")";
    if (o.ended()) break;
  }
}

INSTANTIATE_TEST_SUITE_P(Registered, TaskConformance, ::testing::ValuesIn(default_cases()),
                         [](const auto& info) { return info.param.label; });
INSTANTIATE_TEST_SUITE_P(TermsConfigs, TaskConformance, ::testing::ValuesIn(terms_cases()),
                         [](const auto& info) { return info.param.label; });
INSTANTIATE_TEST_SUITE_P(Variants, TaskConformance, ::testing::ValuesIn(variant_cases()),
                         [](const auto& info) { return info.param.label; });

}  // namespace
}  // namespace farm::robots
