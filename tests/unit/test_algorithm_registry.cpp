// The algorithm registry: every registered algorithm builds for a task that fits it, refuses one
// that does not, saves and loads its networks in its own sub-folder, reads them back as the
// workers' policy (for farm-policy-file), runs in the pacing of its kind, exports its policy in the
// Torch-free tools build from the config (common/policy_shape.h), and the config's algorithm
// sections and the registry name the same algorithms. DQN's exploration clock survives a resume.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <set>
#include <stdexcept>
#include <string>

#include "batch.h"
#include "config.h"
#include "dqn.h"
#include "pacing.h"
#include "paths.h"  // remove_tree: std::filesystem::remove_all crashes the GPU build
#include "policy_shape.h"
#include "registry.h"
#include "task_specs.h"

namespace {

namespace fs = std::filesystem;

farm::robots::TaskSpec continuous_spec() {
  farm::robots::TaskSpec s;
  s.name = "test_continuous";
  s.obs_dim = 3;
  s.act_dim = 1;
  s.max_episode_steps = 200;
  s.metric_names = {"m"};
  return s;
}

farm::robots::TaskSpec discrete_spec() {
  farm::robots::TaskSpec s = continuous_spec();
  s.name = "test_discrete";
  s.num_actions = 4;
  return s;
}

farm::config::ExperimentConfig config_for(const std::string& algorithm) {
  const std::string text = "experiment_id: \"registry_test\"\nalgorithm: \"" + algorithm +
                           "\"\nsac { hidden: [8, 8] }\ndqn { hidden: [8] }\nppo { hidden: [8, 8] }\n"
                           "td3 { hidden: [8, 8] critic_hidden: [8, 8] }\n"
                           "fastsac { hidden: [8, 8] critic_hidden: [8, 8] }\n";
  return farm::robots::parse_config_text(text, "registry_test.txtpb");
}

// The spec an algorithm is meant for: DQN takes discrete actions, the others continuous ones.
bool wants_discrete(const std::string& name) { return name == "dqn"; }

TEST(AlgorithmRegistry, NamesAreUniqueAndEachHasAMaker) {
  std::set<std::string> seen;
  ASSERT_FALSE(farm::algorithms().empty());
  for (const auto& a : farm::algorithms()) {
    EXPECT_TRUE(seen.insert(a.name).second) << "registered twice: " << a.name;
    EXPECT_NE(a.make, nullptr) << a.name;
  }
}

TEST(AlgorithmRegistry, ConfigSectionsAndRegistryNameTheSameAlgorithms) {
  const std::vector<std::string> sections = farm::algorithm_sections();
  const std::vector<std::string> registered = farm::algorithm_names();
  EXPECT_EQ(std::set<std::string>(sections.begin(), sections.end()),
            std::set<std::string>(registered.begin(), registered.end()))
      << "an algorithm needs its config section in farm_config.proto, marked (algorithm_section), and one line "
         "in learner/algorithms/registry.cpp";
}

TEST(AlgorithmRegistry, EveryAlgorithmBuildsSavesAndLoads) {
  const fs::path dir = fs::temp_directory_path() / ("farm_registry_" + std::to_string(::getpid()));
  for (const auto& a : farm::algorithms()) {
    SCOPED_TRACE(a.name);
    const auto cfg = config_for(a.name);
    const auto spec = wants_discrete(a.name) ? discrete_spec() : continuous_spec();
    auto algo = farm::make_algorithm(cfg, spec);
    ASSERT_NE(algo, nullptr);
    EXPECT_EQ(algo->name(), a.name);
    EXPECT_FALSE(algo->describe().empty());
    EXPECT_EQ(algo->updates(), 0);
    EXPECT_EQ(algo->ready(), 0) << "no data, no update";
    farm::remove_tree(dir.string());
    fs::create_directories(dir);
    algo->save_networks(dir.string());
    EXPECT_TRUE(fs::is_directory(dir / a.name)) << "networks go to the sub-folder named for the algorithm";
    // What the programs that write a policy file load: the saved networks as the workers' policy.
    int64_t updates = -1;
    const farm::PolicyParams p = farm::read_saved_policy(cfg, spec, dir.string(), 7, &updates);
    EXPECT_EQ(p.version, 7u);
    EXPECT_EQ(updates, 0);
    EXPECT_EQ(farm::Policy(p).obs_dim(), spec.obs_dim);
    EXPECT_EQ(farm::Policy(p).act_dim(), spec.act_dim);
    EXPECT_THROW(farm::read_saved_policy(cfg, spec, (dir / "no_such_folder").string(), 7, &updates),
                 std::runtime_error);
    auto again = farm::make_algorithm(cfg, spec);
    algo->save(dir.string());
    EXPECT_NO_THROW(again->load(dir.string()));
    // A pacing of the registration's kind runs it (learner/pacing.h).
    const auto paced = farm::make_pacing(cfg, spec);
    EXPECT_EQ(paced->csv_header().rfind("elapsed_s,", 0), 0u) << paced->csv_header();
    EXPECT_TRUE(std::isnan(paced->last_eval()));
    EXPECT_EQ(paced->describe(), algo->describe());
  }
  farm::remove_tree(dir.string());
}

TEST(AlgorithmRegistry, ATaskOfTheWrongActionSpaceIsRefusedByName) {
  for (const auto& a : farm::algorithms()) {
    SCOPED_TRACE(a.name);
    const auto spec = wants_discrete(a.name) ? continuous_spec() : discrete_spec();
    try {
      farm::make_algorithm(config_for(a.name), spec);
      FAIL() << "built for the wrong action space";
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(a.name), std::string::npos) << e.what();
    }
  }
}

TEST(AlgorithmRegistry, UnknownNamesAreRefused) {
  try {
    farm::find_algorithm("a3c");
    FAIL() << "unknown algorithm accepted";
  } catch (const std::invalid_argument& e) {
    const std::string what = e.what();
    for (const auto& n : farm::algorithm_names()) EXPECT_NE(what.find(n), std::string::npos) << what;
  }
}

// What the learner exports is what common/policy_shape.h gives for the config: the tools that show
// an untrained policy (farm-play --config) build it from that shape without LibTorch.
void expect_same_shape(const farm::PolicyParams& shape, const farm::PolicyParams& policy) {
  EXPECT_EQ(int(shape.head), int(policy.head));
  EXPECT_EQ(shape.layout.sizes, policy.layout.sizes);
  EXPECT_EQ(int(shape.layout.activation), int(policy.layout.activation));
  EXPECT_EQ(shape.log_std_min, policy.log_std_min);
  EXPECT_EQ(shape.log_std_max, policy.log_std_max);
  EXPECT_EQ(shape.log_std, policy.log_std);  // PPO: its initial log-std
  EXPECT_EQ(shape.obs_mean.size(), policy.obs_mean.size());
  EXPECT_EQ(shape.obs_std.size(), policy.obs_std.size());
  EXPECT_TRUE(shape.params.empty());
  EXPECT_EQ(policy.params.size(), policy.layout.num_params());
}

TEST(AlgorithmRegistry, ExportedPoliciesHaveTheConfigsShape) {
  for (const auto& a : farm::algorithms()) {
    SCOPED_TRACE(a.name);
    auto cfg = config_for(a.name);
    const auto spec = wants_discrete(a.name) ? discrete_spec() : continuous_spec();
    for (const char* activation : {"relu", "tanh"}) {
      cfg.mutable_sac()->set_activation(activation);
      cfg.mutable_ppo()->set_activation(activation);
      cfg.mutable_ppo()->set_initial_log_std(-0.5);
      int64_t updates = -1;
      expect_same_shape(farm::policy_shape(cfg, spec), farm::read_saved_policy(cfg, spec, "", 0, &updates));
      const farm::PolicyParams untrained = farm::untrained_policy(cfg, spec);
      expect_same_shape(farm::policy_shape(cfg, spec), untrained);
      EXPECT_NO_THROW(farm::Policy{untrained});
    }
  }
}

TEST(AlgorithmRegistry, UntrainedPoliciesFollowTheSeed) {
  auto cfg = config_for("sac");
  const auto a = farm::untrained_policy(cfg, continuous_spec());
  EXPECT_EQ(a.params, farm::untrained_policy(cfg, continuous_spec()).params);
  cfg.set_seed(cfg.seed() + 1);
  EXPECT_NE(a.params, farm::untrained_policy(cfg, continuous_spec()).params);
  // Within +-1/sqrt(fan_in) of each layer: the first layer's fan-in is the 3 observations.
  for (int i = 0; i < 8 * 3; ++i) EXPECT_LE(std::abs(a.params[i]), 1 / std::sqrt(3.f));
  auto dqn = config_for("dqn");
  EXPECT_THROW(farm::policy_shape(dqn, continuous_spec()), std::invalid_argument);
  dqn.set_algorithm("a2c");
  EXPECT_THROW(farm::policy_shape(dqn, discrete_spec()), std::invalid_argument);
}

// One batch of `rows` one-step transitions of the 3-observation test task, action 1.
struct Rows {
  explicit Rows(int rows) : truncated(size_t(rows), 0) {
    t.n = rows;
    t.obs.assign(size_t(rows) * 3, 0.5f);
    t.actions.assign(size_t(rows), 1.f);
    t.rewards.assign(size_t(rows), 1.f);
    t.next_obs.assign(size_t(rows) * 3, 0.4f);
    t.terminated.assign(size_t(rows), 0);
    batch.num_steps = 1;
    batch.num_envs = rows;
    batch.truncated = truncated.data();
    batch.rows = &t;
  }
  farm::Transitions t;
  std::vector<uint8_t> truncated;
  farm::Batch batch;
};

// DQN's epsilon follows the env steps inserted. A resumed run carries on from every step the
// checkpoint's accounts hold (the manifest's env_steps), not only those up to the last version
// exported before the checkpoint.
TEST(DqnAlgorithm, ExplorationResumesFromEveryStepTheCheckpointHolds) {
  const auto cfg = farm::robots::parse_config_text(
      "experiment_id: \"dqn_resume\"\nalgorithm: \"dqn\"\n"
      "dqn { hidden: [8] buffer_size: 1000 batch_size: 4 learning_starts: 0 schedule_env_steps: 1000 "
      "exploration_fraction: 1 }\n",
      "dqn_resume.txtpb");
  const fs::path dir = fs::temp_directory_path() / ("farm_dqn_resume_" + std::to_string(::getpid()));
  farm::remove_tree(dir.string());
  fs::create_directories(dir);
  auto algo = farm::make_algorithm(cfg, discrete_spec());
  algo->insert(Rows(100).batch);
  EXPECT_FLOAT_EQ(algo->policy(1).epsilon, float(farm::dqn_epsilon(cfg.dqn(), 100)));
  algo->insert(Rows(300).batch);  // after version 1 was exported, before the checkpoint
  algo->save(dir.string());
  farm::config::CheckpointManifest m;
  algo->to_manifest(m);
  m.set_env_steps(400);  // the learner's accounts: every step it accepted
  auto resumed = farm::make_algorithm(cfg, discrete_spec());
  resumed->load(dir.string());
  resumed->from_manifest(m);
  EXPECT_FLOAT_EQ(resumed->policy(2).epsilon, float(farm::dqn_epsilon(cfg.dqn(), 400)));
  EXPECT_FLOAT_EQ(algo->policy(2).epsilon, float(farm::dqn_epsilon(cfg.dqn(), 400)));
  farm::remove_tree(dir.string());
}

// On the CPU a batch four times as large costs about four times the time (bench_dqn), so DQN keeps
// the configured step there whatever dqn.max_step_scale says, and its start line says so. Where the
// pacing sets a scale, the minibatch follows it.
TEST(DqnAlgorithm, TheCpuKeepsTheConfiguredStep) {
  const auto cfg = farm::robots::parse_config_text(
      "experiment_id: \"dqn_scale\"\nalgorithm: \"dqn\"\n"
      "dqn { hidden: [8] buffer_size: 1000 batch_size: 16 learning_starts: 0 max_step_scale: 4 device: \"cpu\" }\n",
      "dqn_scale.txtpb");
  auto algo = farm::make_algorithm(cfg, discrete_spec());
  EXPECT_EQ(algo->max_step_scale(), 1);
  EXPECT_NE(algo->describe().find("the configured step (dqn.max_step_scale is for a GPU learner)"), std::string::npos)
      << algo->describe();
  algo->insert(Rows(32).batch);
  EXPECT_GT(algo->ready(), 0) << "32 rows hold a minibatch of 16";
  algo->set_step_scale(4);
  EXPECT_EQ(algo->ready(), 0) << "32 rows do not hold one of 4 x 16";
  algo->insert(Rows(32).batch);
  EXPECT_GT(algo->ready(), 0);
  EXPECT_EQ(algo->update(1, 1).size(), 1u);
}

}  // namespace
