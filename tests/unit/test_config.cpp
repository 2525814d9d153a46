// Config errors must name the file, the line and the field, and defaults must be the schema's.
#include <gtest/gtest.h>

#include <filesystem>

#include <cmath>
#include <fstream>
#include <string>
#include <vector>

#include "config.h"
#include "mclari/mclari_spec.h"
#include "mobile/mobile_spec.h"
#include "pendulum/pendulum_spec.h"
#include "quadruped/quadruped_spec.h"
#include "task_specs.h"

using farm::ConfigError;
using farm::robots::parse_config_text;

namespace {

std::string error_of(const std::string& text) {
  try {
    parse_config_text(text, "exp.txtpb");
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST(Config, DefaultsComeFromTheSchema) {
  auto c = parse_config_text("experiment_id: \"a\"\n", "exp.txtpb");
  EXPECT_EQ(c.sac().batch_size(), 256);
  EXPECT_DOUBLE_EQ(c.sac().gamma(), 0.99);
  EXPECT_DOUBLE_EQ(c.sac().tau(), 0.005);
  EXPECT_TRUE(std::isnan(c.sac().target_entropy()));
  EXPECT_DOUBLE_EQ(c.task().pendulum().max_torque(), 2.0);
  EXPECT_EQ(c.task().pendulum().max_episode_steps(), 200);
  EXPECT_EQ(farm::sac_hidden(c.sac()), (std::vector<int>{256, 256}));
  EXPECT_EQ(c.task().name(), "pendulum");
}

TEST(Config, MisspelledFieldNamesFileLineAndField) {
  std::string e = error_of("experiment_id: \"a\"\nsac {\n  batch_size: 64\n  lerning_rate: 0.1\n}\n");
  EXPECT_NE(e.find("exp.txtpb:4:"), std::string::npos) << e;
  EXPECT_NE(e.find("lerning_rate"), std::string::npos) << e;
}

TEST(Config, WrongTypeNamesTheLine) {
  std::string e = error_of("experiment_id: \"a\"\nseed: \"many\"\n");
  EXPECT_NE(e.find("exp.txtpb:2:"), std::string::npos) << e;
}

TEST(Config, OutOfRangeValueNamesFieldLineAndExpectation) {
  std::string e = error_of("experiment_id: \"a\"\n\nsac {\n  gamma: 0.9\n  batch_size: -3\n}\n");
  EXPECT_NE(e.find("exp.txtpb:5:"), std::string::npos) << e;
  EXPECT_NE(e.find("sac.batch_size"), std::string::npos) << e;
  EXPECT_NE(e.find("expected > 0, got -3"), std::string::npos) << e;
}

TEST(Config, EvaluationSplitIsCheckedAndDefaultsToFourEpisodesAWorker) {
  EXPECT_EQ(parse_config_text("experiment_id: \"a\"\n", "exp.txtpb").eval().min_episodes_per_worker(), 4);
  std::string e = error_of("experiment_id: \"a\"\neval {\n  min_episodes_per_worker: -1\n}\n");
  EXPECT_NE(e.find("exp.txtpb:3:"), std::string::npos) << e;
  EXPECT_NE(e.find("eval.min_episodes_per_worker"), std::string::npos) << e;
  EXPECT_NE(e.find("expected >= 0 (0 = every evaluation on one worker), got -1"), std::string::npos) << e;
}

namespace {

// The off-policy algorithms' sections, each as a config opens before it and the line it is on.
struct OffPolicySection {
  std::string head, section, line;
};
std::vector<OffPolicySection> off_policy_sections() {
  return {{"experiment_id: \"a\"\n", "sac", "exp.txtpb:3:"},
          {"experiment_id: \"a\"\nalgorithm: \"dqn\"\n", "dqn", "exp.txtpb:4:"}};
}

}  // namespace

// A resume may change what it likes but the algorithm and, where replay rows sum several rewards,
// the gamma they were discounted with (rows carry their horizon, so n_step may change).
TEST(Config, ResumeKeepsTheDiscountOfSummedReplayRows) {
  const auto cfg = [](const std::string& body) {
    return parse_config_text("experiment_id: \"r\" " + body, "exp.txtpb");
  };
  const auto was = cfg("sac { n_step: 3 gamma: 0.99 }");
  EXPECT_EQ(farm::resume_change(was, cfg("sac { n_step: 5 gamma: 0.99 actor_lr: 1e-4 } stop { max_seconds: 9 }")), "");
  EXPECT_EQ(farm::resume_change(was, cfg("sac { n_step: 3 gamma: 0.98 }")),
            "the checkpoint's replay rows sum up to 3 rewards (sac.n_step) discounted with sac.gamma 0.99, this "
            "config's gamma is 0.98: the rows would mix two discounts (resume with gamma 0.99, or start a new run)");
  // One-step rows hold no discount: gamma may change.
  const std::string dqn = "algorithm: \"dqn\" ";
  EXPECT_EQ(farm::resume_change(cfg(dqn + "dqn { }"), cfg(dqn + "dqn { gamma: 0.9 n_step: 3 }")), "");
  EXPECT_NE(farm::resume_change(cfg(dqn + "dqn { n_step: 2 }"), cfg(dqn + "dqn { n_step: 2 gamma: 0.9 }")), "");
  EXPECT_EQ(farm::resume_change(was, cfg("algorithm: \"ppo\"")),
            "the checkpoint is of algorithm \"sac\", this config's is \"ppo\"");
}

// sac.lr_decay_* and dqn.lr_decay_*: a length of 0 or more and a fraction in (0, 1], an error at the
// field's line otherwise.
TEST(Config, LearningRateScheduleIsChecked) {
  for (const OffPolicySection& c : off_policy_sections()) {
    EXPECT_EQ(error_of(c.head + c.section + " {\n  lr_decay_updates: 1000\n  lr_decay_to: 0.1\n}\n"), "") << c.section;
    std::string e = error_of(c.head + c.section + " {\n  lr_decay_updates: -1\n}\n");
    EXPECT_NE(e.find(c.section + ".lr_decay_updates"), std::string::npos) << e;
    for (const char* bad : {"0", "1.5", "-0.1"}) {
      e = error_of(c.head + c.section + " {\n  lr_decay_to: " + bad + "\n}\n");
      EXPECT_NE(e.find(c.line), std::string::npos) << e;
      EXPECT_NE(e.find(c.section + ".lr_decay_to"), std::string::npos) << e;
      EXPECT_NE(e.find("expected a fraction in (0, 1] of the configured rates"), std::string::npos) << e;
    }
  }
}

// sac.policy_average_tau: 0 (off) to 1, an error naming the field otherwise.
TEST(Config, PolicyAverageTauIsChecked) {
  const std::string head = "experiment_id: \"a\"\n";
  EXPECT_EQ(error_of(head + "sac {\n  policy_average_tau: 0.01\n}\n"), "");
  for (const char* bad : {"-0.1", "1.5"}) {
    const std::string e = error_of(head + "sac {\n  policy_average_tau: " + bad + "\n}\n");
    EXPECT_NE(e.find("sac.policy_average_tau"), std::string::npos) << e;
    EXPECT_NE(e.find("expected 0 (off) to 1"), std::string::npos) << e;
  }
}

// sac.max_step_scale and dqn.max_step_scale: 1 to 64, an error at the field's line otherwise.
TEST(Config, StepScaleIsBounded) {
  for (const OffPolicySection& c : off_policy_sections()) {
    EXPECT_EQ(error_of(c.head + c.section + " {\n  max_step_scale: 4\n}\n"), "") << c.section;
    for (const char* bad : {"0", "65"}) {
      std::string e = error_of(c.head + c.section + " {\n  max_step_scale: " + bad + "\n}\n");
      EXPECT_NE(e.find(c.line), std::string::npos) << e;
      EXPECT_NE(e.find(c.section + ".max_step_scale"), std::string::npos) << e;
      EXPECT_NE(e.find(std::string("expected 1 to 64, got ") + bad), std::string::npos) << e;
    }
  }
}

// worker.exploration_scale_min/max: a range above 0, and only for off-policy continuous actions.
TEST(Config, ExplorationScalesAreARangeForOffPolicyContinuousActions) {
  const std::string w = "worker {\n  exploration_scale_min: 0.4\n  exploration_scale_max: 1.6\n}\n";
  EXPECT_EQ(error_of("experiment_id: \"a\"\n" + w), "");
  EXPECT_EQ(error_of("experiment_id: \"a\"\nalgorithm: \"td3\"\n" + w), "");
  for (const char* algo : {"ppo", "dqn"}) {
    const std::string e = error_of("experiment_id: \"a\"\nalgorithm: \"" + std::string(algo) + "\"\n" + w);
    EXPECT_NE(e.find("worker.exploration_scale_min"), std::string::npos) << e;
    EXPECT_NE(e.find(std::string(algo) + " needs the policy's own noise"), std::string::npos) << e;
  }
  for (const char* bad : {"exploration_scale_min: 0", "exploration_scale_min: 2", "exploration_scale_max: 101"}) {
    const std::string e = error_of("experiment_id: \"a\"\nworker {\n  " + std::string(bad) + "\n}\n");
    EXPECT_NE(e.find("expected 0 < exploration_scale_min <= exploration_scale_max <= 100"), std::string::npos)
        << bad << ": " << e;
  }
}

TEST(Config, NestedTaskFieldIsLocated) {
  std::string e = error_of("experiment_id: \"a\"\ntask {\n  pendulum {\n    dt: 0\n  }\n}\n");
  EXPECT_NE(e.find("exp.txtpb:4:"), std::string::npos) << e;
  EXPECT_NE(e.find("task.pendulum.dt"), std::string::npos) << e;
}

TEST(Config, MissingExperimentIdIsRequired) {
  std::string e = error_of("seed: 3\n");
  EXPECT_NE(e.find("experiment_id"), std::string::npos) << e;
  EXPECT_NE(e.find("required"), std::string::npos) << e;
}

TEST(Config, UnknownAlgorithmListsTheKnownOnes) {
  std::string e = error_of("experiment_id: \"a\"\nalgorithm: \"sacc\"\n");
  EXPECT_NE(e.find("exp.txtpb:2:"), std::string::npos) << e;
  EXPECT_NE(e.find("expected one of: sac"), std::string::npos) << e;
}

TEST(Config, MissingFileIsNamed) {
  try {
    farm::robots::load_config_file("/nonexistent/dir/exp.txtpb");
    FAIL() << "no error";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/dir/exp.txtpb"), std::string::npos);
  }
}

TEST(Config, ShippedConfigsLoad) {
  int n = 0;
  for (const auto& e : std::filesystem::directory_iterator(std::string(FARM_SOURCE_DIR) + "/deploy/configs")) {
    if (e.path().extension() != ".txtpb") continue;
    EXPECT_NO_THROW(farm::robots::load_config_file(e.path().string())) << e.path();
    ++n;
  }
  EXPECT_GE(n, 8);
}

// A limit in env steps ends a run less trained the more workers feed it (the learner's updates
// per env step fall as the steps arrive faster: Kaya with 15 workers stopped untrained at its
// 1,000,000 steps), so a shipped config never stops on a step count. A limit in updates is the
// training itself, the same with 2 workers or 15 and on any host; it comes with a time limit, so
// a slow host still ends the run. Otherwise a shipped config stops on its goal or on time.
TEST(Config, ShippedConfigsStopOnTheirGoalOrOnTime) {
  int n = 0;
  for (const auto& e : std::filesystem::directory_iterator(std::string(FARM_SOURCE_DIR) + "/deploy/configs")) {
    if (e.path().extension() != ".txtpb") continue;
    const auto c = farm::robots::load_config_file(e.path().string());
    EXPECT_EQ(c.stop().max_env_steps(), 0) << e.path() << ": stops on an env step limit";
    if (c.stop().max_updates() > 0)
      EXPECT_GT(c.stop().max_seconds(), 0) << e.path() << ": an update limit without a time limit";
    EXPECT_TRUE(c.stop().max_seconds() > 0 || !std::isnan(c.stop().target_eval_return()))
        << e.path() << ": no time limit and no target";
    ++n;
  }
  EXPECT_GE(n, 8);
}

// The experiment id names the run folder: "." and ".." would name another one.
TEST(Config, ExperimentIdIsASafeFolderName) {
  for (const char* id : {".", "..", "a/b"}) {
    try {
      farm::robots::parse_config_text(std::string("experiment_id: \"") + id + "\"\n", "x.txtpb");
      ADD_FAILURE() << id << " accepted";
    } catch (const farm::ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find("x.txtpb:1:"), std::string::npos) << e.what();
    }
  }
  EXPECT_NO_THROW(farm::robots::parse_config_text("experiment_id: \"run.2\"\n", "x"));
}

// A worker's sizes are bounded where the config is read, with the line named.
TEST(Config, WorkerSizesAreBounded) {
  try {
    farm::robots::parse_config_text("experiment_id: \"w\"\nworker {\n  envs_per_worker: 5000\n}\n", "w.txtpb");
    ADD_FAILURE() << "accepted";
  } catch (const farm::ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("w.txtpb:3:"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("expected 1..4096, got 5000"), std::string::npos) << e.what();
  }
  EXPECT_THROW(farm::robots::parse_config_text("experiment_id: \"w\"\nworker { steps_per_batch: 100000 }\n", "w"),
               farm::ConfigError);
}

// worker.nice lowers a worker's priority; a config (one off the bus included) may not ask a worker
// to raise it, nor name a value setpriority() would clamp.
TEST(Config, WorkerNiceIsAPriorityToLowerTo) {
  EXPECT_EQ(farm::robots::parse_config_text("experiment_id: \"w\"\n", "w").worker().nice(), 0);
  EXPECT_EQ(farm::robots::parse_config_text("experiment_id: \"w\"\nworker { nice: 10 }\n", "w").worker().nice(), 10);
  for (const char* v : {"-5", "20"}) {
    try {
      farm::robots::parse_config_from_bus(std::string("experiment_id: \"w\"\nworker {\n  nice: ") + v + "\n}\n",
                                          "ExperimentSpec(w)");
      ADD_FAILURE() << "nice " << v << " accepted";
    } catch (const farm::ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find("ExperimentSpec(w):3:"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("nice"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(std::string("expected 0..19 (a worker may lower its priority, not raise "
                                                       "it), got ") +
                                           v),
                std::string::npos)
          << e.what();
    }
  }
}

// A config from the bus may not name a file for the receiving host to write.
TEST(Config, ConfigFromTheBusNamesNoFileToWrite) {
  const std::string text = "experiment_id: \"m\"\ntask { name: \"mclari\" mclari { hfield_png: \"/etc/cron.d/x\" } }\n";
  auto cfg = farm::robots::parse_config_text(text, "learner.txtpb");  // the learner's own file may
  ASSERT_EQ(farm::output_path_fields(cfg), std::vector<std::string>{"task.mclari.hfield_png"});
  try {
    farm::robots::parse_config_from_bus(text, "ExperimentSpec(m)");
    ADD_FAILURE() << "accepted";
  } catch (const farm::ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("ExperimentSpec(m): field 'task.mclari.hfield_png' names a file"),
              std::string::npos)
        << e.what();
  }
  farm::clear_output_paths(&cfg);
  EXPECT_TRUE(farm::output_path_fields(cfg).empty());
  EXPECT_EQ(cfg.task().name(), "mclari");
  EXPECT_NO_THROW(farm::robots::parse_config_from_bus(farm::config_to_text(cfg), "ExperimentSpec(m)"));
}

// A field this program does not know, in a config from the bus, means the learner was built from
// newer sources than this worker: the error says so (its own wording names only the field).
TEST(Config, UnknownFieldFromTheBusSaysTheWorkerIsOlder) {
  try {
    farm::robots::parse_config_from_bus("experiment_id: \"m\"\nsac { field_of_a_newer_build: true }\n",
                                        "ExperimentSpec(m)");
    ADD_FAILURE() << "accepted";
  } catch (const farm::ConfigError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("ExperimentSpec(m):2:"), std::string::npos) << what;
    EXPECT_NE(what.find("field_of_a_newer_build"), std::string::npos) << what;
    EXPECT_EQ(what.rfind("ExperimentSpec(m) was written by a newer build than this program", 0), 0u) << what;
  }
  try {
    farm::robots::parse_config_text("sac { field_of_a_newer_build: true }\n", "mine.txtpb");
    ADD_FAILURE() << "accepted";
  } catch (const farm::ConfigError& e) {
    EXPECT_EQ(std::string(e.what()).find("newer build"), std::string::npos) << "a local file: " << e.what();
  }
}

TEST(Config, TextRoundTrip) {
  auto c = parse_config_text("experiment_id: \"rt\"\nsac { hidden: 64 hidden: 64 }\n", "x");
  auto d = parse_config_text(farm::config_to_text(c), "y");
  EXPECT_EQ(d.experiment_id(), "rt");
  EXPECT_EQ(farm::sac_hidden(d.sac()), (std::vector<int>{64, 64}));
}

TEST(Config, LearnerDeviceDefaultsToCpuAndIsChecked) {
  EXPECT_EQ(parse_config_text("experiment_id: \"a\"\n", "exp.txtpb").sac().device(), "cpu");
  EXPECT_EQ(parse_config_text("experiment_id: \"a\"\nsac { device: \"cuda:1\" }\n", "exp.txtpb").sac().device(),
            "cuda:1");
  std::string e = error_of("experiment_id: \"a\"\nsac {\n  device: \"gpu\"\n}\n");
  EXPECT_NE(e.find("exp.txtpb:3:"), std::string::npos) << e;
  EXPECT_NE(e.find("sac.device"), std::string::npos) << e;
  EXPECT_NE(e.find("\"gpu\""), std::string::npos) << e;
  // "auto": the GPU where the learner sees one, else the CPU (a shipped config runs on either).
  EXPECT_EQ(parse_config_text("experiment_id: \"a\"\nppo { device: \"auto\" }\n", "exp.txtpb").ppo().device(), "auto");
  e = error_of("experiment_id: \"a\"\nalgorithm: \"ppo\"\nppo {\n  device: \"automatic\"\n}\n");
  EXPECT_NE(e.find("ppo.device"), std::string::npos) << e;
  EXPECT_NE(e.find("\"auto\""), std::string::npos) << e;
  EXPECT_EQ(parse_config_text("experiment_id: \"a\"\n", "exp.txtpb").dqn().device(), "cpu");
  e = error_of("experiment_id: \"a\"\nalgorithm: \"dqn\"\ndqn {\n  device: \"cuda:x\"\n}\n");
  EXPECT_NE(e.find("exp.txtpb:4:"), std::string::npos) << e;
  EXPECT_NE(e.find("dqn.device"), std::string::npos) << e;
  EXPECT_NE(e.find("\"cuda:x\""), std::string::npos) << e;
}

// Every task section is range-checked where the config is read, so the error names the file, the
// line, the column and the field path; a task's constructor knows none of them.
TEST(Config, TaskSectionErrorsNameFileLineAndField) {
  struct Case {
    const char* task;
    const char* section;  // written at line 4, column 3 of the file
    const char* error;
  };
  const Case cases[] = {
      {"pendulum", "pendulum {\n    gravity: 0\n  }",
       "exp.txtpb:5:5: field 'task.pendulum.gravity': expected > 0, got 0"},
      {"pendulum", "pendulum {\n    dt: inf\n  }",
       "exp.txtpb:5:5: field 'task.pendulum.dt': expected a finite value, got inf"},
      {"cartpole", "cartpole {\n    gear: 0\n  }", "exp.txtpb:5:5: field 'task.cartpole.gear': expected > 0, got 0"},
      {"cartpole", "cartpole {\n    init_noise: -1\n  }",
       "exp.txtpb:5:5: field 'task.cartpole.init_noise': expected >= 0, got -1"},
      {"a1", "a1 {\n    decimation: 0\n  }", "exp.txtpb:5:5: field 'task.a1.decimation': expected >= 1, got 0"},
      {"honey_badger", "honey_badger {\n    kp_rel: 1\n  }",
       "exp.txtpb:5:5: field 'task.honey_badger.kp_rel': expected in [0, 1), got 1"},
      {"silver_badger", "silver_badger {\n    friction_min: 2\n  }",
       "exp.txtpb:5:5: field 'task.silver_badger.friction_min': "
       "expected 0 < friction_min <= friction_max (1.25), got 2"},
      {"a1", "a1 {\n    reward { tracking_lin_vel: 1 }\n    physics_dt: 0.1\n  }",
       "exp.txtpb:6:5: field 'task.a1.physics_dt': expected in (0, 0.05], got 0.1"},
      {"jetbot", "jetbot {\n    wheel_kv: 0\n  }", "exp.txtpb:5:5: field 'task.jetbot.wheel_kv': expected > 0, got 0"},
      {"kaya", "kaya {\n    max_linear_speed: -1\n  }",
       "exp.txtpb:5:5: field 'task.kaya.max_linear_speed': expected > 0, got -1"},
      {"jetbot", "jetbot {\n    scene {\n      lidar_rays: 0\n    }\n  }",
       "exp.txtpb:6:7: field 'task.jetbot.scene.lidar_rays': expected in [1, 1024], got 0"},
      {"kaya", "kaya {\n    scene {\n      min_obstacles: 3\n      max_obstacles: 2\n    }\n  }",
       "exp.txtpb:7:7: field 'task.kaya.scene.max_obstacles': expected >= min_obstacles (3), got 2"},
      // A field left at its default is named by the section the file writes.
      {"jetbot", "jetbot {\n    scene {\n      min_obstacles: 10\n    }\n  }",
       "exp.txtpb:5:5: field 'task.jetbot.scene.max_obstacles': expected >= min_obstacles (10), got 8"},
      {"jetbot", "jetbot {\n    scene {\n      obstacle_max_half_size: 3\n    }\n  }",
       "exp.txtpb:6:7: field 'task.jetbot.scene.obstacle_max_half_size': expected < arena_half_size (2), got 3"},
      {"mclari", "mclari {\n    voltage: -1\n  }", "exp.txtpb:5:5: field 'task.mclari.voltage': expected > 0, got -1"},
      {"mclari", "mclari {\n    initial_frequency: 200\n  }",
       "exp.txtpb:5:5: field 'task.mclari.initial_frequency': "
       "expected in [min_frequency, max_frequency] = [1, 150], got 200"},
      {"mclari", "mclari {\n    hfield_filter: 2\n  }",
       "exp.txtpb:5:5: field 'task.mclari.hfield_filter': expected odd and >= 1, got 2"},
      {"mclari", "mclari {\n    hfield_size: 1\n  }",
       "exp.txtpb:5:5: field 'task.mclari.hfield_size': expected >= 2, got 1"},
      {"mclari", "mclari {\n    terrains: 0\n    terrains: 6\n  }",
       "exp.txtpb:6:5: field 'task.mclari.terrains': entries must be in [0, 6), got 6"},
      {"mclari", "mclari {\n    groups: 3\n    groups: 3\n  }",
       "exp.txtpb:6:5: field 'task.mclari.groups': lists group 3 twice"},
  };
  for (const Case& c : cases) {
    const std::string text =
        std::string("experiment_id: \"a\"\ntask {\n  name: \"") + c.task + "\"\n  " + c.section + "\n}\n";
    EXPECT_EQ(error_of(text), c.error) << text;
  }
}

// Only the section of the task that runs is checked: the others are never used.
TEST(Config, UnusedTaskSectionsAreNotChecked) {
  EXPECT_NO_THROW(parse_config_text("experiment_id: \"a\"\ntask {\n  name: \"a1\"\n  cartpole { gear: 0 }\n}\n", "x"));
  EXPECT_NE(error_of("experiment_id: \"a\"\ntask {\n  name: \"cartpole\"\n  cartpole { gear: 0 }\n}\n"), "");
}

// The algorithms' own checks are the loader's too, with the line named.
TEST(Config, AlgorithmSectionErrorsNameFileLineAndField) {
  EXPECT_EQ(error_of("experiment_id: \"a\"\nalgorithm: \"ppo\"\nppo {\n  kl_band: 1\n}\n"),
            "exp.txtpb:4:3: field 'ppo.kl_band': expected > 1, got 1");
  EXPECT_EQ(error_of("experiment_id: \"a\"\nalgorithm: \"ppo\"\nppo {\n  eval_every_fits: -1\n}\n"),
            "exp.txtpb:4:3: field 'ppo.eval_every_fits': expected >= 0 (0: only at the end), got -1");
  EXPECT_EQ(error_of("experiment_id: \"a\"\nalgorithm: \"dqn\"\ndqn {\n  n_step: 0\n}\n"),
            "exp.txtpb:4:3: field 'dqn.n_step': expected >= 1, got 0");
  EXPECT_EQ(error_of("experiment_id: \"a\"\nalgorithm: \"sac\"\nsac {\n  n_step: 0\n}\n"),
            "exp.txtpb:4:3: field 'sac.n_step': expected >= 1, got 0");
  // Updates wait for learning_starts rows in the replay buffer, which holds buffer_size at most.
  EXPECT_EQ(error_of("experiment_id: \"a\"\nalgorithm: \"dqn\"\ndqn {\n  buffer_size: 20000\n}\n"),
            "exp.txtpb:3:1: field 'dqn.learning_starts': expected <= dqn.buffer_size (20000), since updates wait "
            "for this many rows in the replay buffer; got 50000");
  EXPECT_EQ(error_of("experiment_id: \"a\"\nsac {\n  learning_starts: 5001\n  buffer_size: 5000\n}\n"),
            "exp.txtpb:3:3: field 'sac.learning_starts': expected <= sac.buffer_size (5000), since updates wait "
            "for this many rows in the replay buffer; got 5001");
  EXPECT_EQ(error_of("experiment_id: \"a\"\nsac {\n  learning_starts: 5000\n  buffer_size: 5000\n}\n"), "");
  // The asynchronous mode fits data of recent versions: a window of 0 would use none of it.
  EXPECT_EQ(error_of("experiment_id: \"a\"\nalgorithm: \"ppo\"\nppo {\n  mode: \"async\"\n}\n"),
            "exp.txtpb:4:3: field 'ppo.mode': \"async\" fits data of recent versions: needs ppo.max_policy_lag >= 1, "
            "got 0");
  EXPECT_EQ(error_of("experiment_id: \"a\"\nalgorithm: \"ppo\"\nppo {\n  mode: \"later\"\n}\n"),
            "exp.txtpb:4:3: field 'ppo.mode': expected \"sync\" or \"async\", got \"later\"");
  // Hidden activations: PPO has tanh, relu and elu; SAC tanh and relu.
  for (const char* a : {"tanh", "relu", "elu"}) {
    EXPECT_EQ(
        error_of("experiment_id: \"a\"\nalgorithm: \"ppo\"\nppo {\n  activation: \"" + std::string(a) + "\"\n}\n"), "")
        << a;
  }
  EXPECT_EQ(error_of("experiment_id: \"a\"\nalgorithm: \"ppo\"\nppo {\n  hidden: 8\n  activation: \"gelu\"\n}\n"),
            "exp.txtpb:5:3: field 'ppo.activation': expected \"tanh\", \"relu\" or \"elu\", got \"gelu\"");
  EXPECT_EQ(error_of("experiment_id: \"a\"\nsac {\n  activation: \"elu\"\n}\n"),
            "exp.txtpb:3:3: field 'sac.activation': expected \"relu\" or \"tanh\", got \"elu\"");
}

// Networks within the bounds every worker holds a received network to (common/mlp.h): a config
// beyond them trained weights that every worker then refused.
TEST(Config, HiddenLayersWithinTheNetworkBounds) {
  EXPECT_EQ(error_of("experiment_id: \"a\"\nsac {\n  hidden: 1048576\n}\n"), "");
  EXPECT_EQ(error_of("experiment_id: \"a\"\nsac {\n  hidden: 64\n  critic_hidden: 1048577\n}\n"),
            "exp.txtpb:4:3: field 'sac.critic_hidden': expected sizes in 1..1048576, got 1048577");
  std::string deep = "experiment_id: \"a\"\nalgorithm: \"ppo\"\nppo {\n";
  for (int i = 0; i < 64; ++i) deep += "  hidden: 4\n";
  EXPECT_NE(error_of(deep + "}\n").find("field 'ppo.hidden': expected at most 63 hidden layers, got 64"),
            std::string::npos)
      << error_of(deep + "}\n");
}

TEST(Config, TheKeptBestIsByReturnOrANamedMetric) {
  const std::string head = "experiment_id: \"a\"\ntask { name: \"mclari\" }\neval {\n";
  EXPECT_EQ(error_of(head + "  best_metric: \"share\"\n  best_reduce: \"min\"\n}\n"), "");
  EXPECT_EQ(error_of(head + "  best_metric: \"shares\"\n}\n"),
            "exp.txtpb:4:3: field 'eval.best_metric': \"shares\" is not one of task 'mclari': efficiency, fell, "
            "reached, terrain, mean_frequency, final_distance, share (empty: the mean return)");
  EXPECT_EQ(error_of(head + "  best_reduce: \"max\"\n}\n"),
            "exp.txtpb:4:3: field 'eval.best_reduce': expected \"mean\" or \"min\", got \"max\"");
}

TEST(Config, EvaluationGoalsNameTheTasksMetrics) {
  const std::string head = "experiment_id: \"a\"\ntask { name: \"a1\" }\nstop {\n";
  EXPECT_EQ(error_of(head + "  eval_goal { metric: \"tracking_lin\" at_least: 0.6 }\n  eval_goal { metric: "
                            "\"walking\" below: 0.1 }\n}\n"),
            "exp.txtpb:5:3: field 'stop.eval_goal': metric \"walking\" is not one of task 'a1': tracking_lin, "
            "tracking_ang, lin_vel_error, fell, time_s");
  EXPECT_EQ(error_of(head + "  eval_goal { metric: \"fell\" }\n}\n"),
            "exp.txtpb:4:3: field 'stop.eval_goal': metric \"fell\": set at_least, below or both");
  EXPECT_EQ(error_of(head + "  eval_goal { metric: \"fell\" below: 0.1 }\n}\n"), "");
  // A task name nobody knows has no metrics: an error, not an exception of another kind (found by
  // fuzz_config).
  EXPECT_EQ(error_of("experiment_id: \"a\"\ntask { name: \"kayak\" }\nstop {\n  eval_goal { metric: \"success\" "
                     "at_least: 0.9 }\n}\n"),
            "exp.txtpb:4:3: field 'stop.eval_goal': a goal names one of the task's metrics: no task spec for task "
            "'kayak'");
}

// A section built in code (a unit test, a tool that changes a loaded config) gets the loader's
// checks through check_config; with no file to name, the error names the field path.
TEST(Config, SectionsBuiltInCodeAreCheckedAlike) {
  farm::config::PendulumConfig p;
  p.set_length(-1);
  try {
    farm::check_config(p);
    ADD_FAILURE() << "accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_STREQ(e.what(), "field 'task.pendulum.length': expected > 0, got -1");
  }
  farm::config::LeggedConfig a1;
  a1.set_kp(0);
  EXPECT_THROW(farm::check_config(a1, "a1"), std::invalid_argument);
  farm::config::JetbotConfig j;
  j.mutable_scene()->set_lidar_rays(2000);
  EXPECT_THROW(farm::check_config(j), std::invalid_argument);
  EXPECT_NO_THROW(farm::check_config(farm::config::MclariConfig{}));
  EXPECT_NO_THROW(farm::check_config(farm::config::PpoConfig{}));
}
