// Config errors must name the file, the line and the field, and defaults must be the schema's.
#include <gtest/gtest.h>

#include <filesystem>

#include <cmath>
#include <fstream>

#include "config.h"

using farm::ConfigError;
using farm::parse_config_text;

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
    farm::load_config_file("/nonexistent/dir/exp.txtpb");
    FAIL() << "no error";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/dir/exp.txtpb"), std::string::npos);
  }
}

TEST(Config, ShippedConfigsLoad) {
  int n = 0;
  for (const auto& e : std::filesystem::directory_iterator(std::string(FARM_SOURCE_DIR) + "/deploy/configs")) {
    if (e.path().extension() != ".txtpb") continue;
    EXPECT_NO_THROW(farm::load_config_file(e.path().string())) << e.path();
    ++n;
  }
  EXPECT_GE(n, 8);
}

// A limit in env steps (or updates) ends a run sooner the more workers feed it, so a shipped
// config stops on its goal or on time, never on a step count.
TEST(Config, ShippedConfigsStopOnTheirGoalOrOnTime) {
  int n = 0;
  for (const auto& e : std::filesystem::directory_iterator(std::string(FARM_SOURCE_DIR) + "/deploy/configs")) {
    if (e.path().extension() != ".txtpb") continue;
    const auto c = farm::load_config_file(e.path().string());
    EXPECT_EQ(c.stop().max_env_steps(), 0) << e.path() << ": stops on an env step limit";
    EXPECT_EQ(c.stop().max_updates(), 0) << e.path() << ": stops on an update limit";
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
      farm::parse_config_text(std::string("experiment_id: \"") + id + "\"\n", "x.txtpb");
      ADD_FAILURE() << id << " accepted";
    } catch (const farm::ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find("x.txtpb:1:"), std::string::npos) << e.what();
    }
  }
  EXPECT_NO_THROW(farm::parse_config_text("experiment_id: \"run.2\"\n", "x"));
}

// A worker's sizes are bounded where the config is read, with the line named.
TEST(Config, WorkerSizesAreBounded) {
  try {
    farm::parse_config_text("experiment_id: \"w\"\nworker {\n  envs_per_worker: 5000\n}\n", "w.txtpb");
    ADD_FAILURE() << "accepted";
  } catch (const farm::ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("w.txtpb:3:"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("expected 1..4096, got 5000"), std::string::npos) << e.what();
  }
  EXPECT_THROW(farm::parse_config_text("experiment_id: \"w\"\nworker { steps_per_batch: 100000 }\n", "w"),
               farm::ConfigError);
}

// A config from the bus may not name a file for the receiving host to write.
TEST(Config, ConfigFromTheBusNamesNoFileToWrite) {
  const std::string text =
      "experiment_id: \"m\"\ntask { name: \"mclari\" mclari { hfield_png: \"/etc/cron.d/x\" } }\n";
  auto cfg = farm::parse_config_text(text, "learner.txtpb");  // the learner's own file may
  ASSERT_EQ(farm::output_path_fields(cfg), std::vector<std::string>{"task.mclari.hfield_png"});
  try {
    farm::parse_config_from_bus(text, "ExperimentSpec(m)");
    ADD_FAILURE() << "accepted";
  } catch (const farm::ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("ExperimentSpec(m): field 'task.mclari.hfield_png' names a file"),
              std::string::npos) << e.what();
  }
  farm::clear_output_paths(&cfg);
  EXPECT_TRUE(farm::output_path_fields(cfg).empty());
  EXPECT_EQ(cfg.task().name(), "mclari");
  EXPECT_NO_THROW(farm::parse_config_from_bus(farm::config_to_text(cfg), "ExperimentSpec(m)"));
}

TEST(Config, TextRoundTrip) {
  auto c = parse_config_text("experiment_id: \"rt\"\nsac { hidden: 64 hidden: 64 }\n", "x");
  auto d = parse_config_text(farm::config_to_text(c), "y");
  EXPECT_EQ(d.experiment_id(), "rt");
  EXPECT_EQ(farm::sac_hidden(d.sac()), (std::vector<int>{64, 64}));
}

TEST(Config, LearnerDeviceDefaultsToCpuAndIsChecked) {
  EXPECT_EQ(parse_config_text("experiment_id: \"a\"\n", "exp.txtpb").sac().device(), "cpu");
  EXPECT_EQ(parse_config_text("experiment_id: \"a\"\nsac { device: \"cuda:1\" }\n", "exp.txtpb")
                .sac()
                .device(),
            "cuda:1");
  std::string e = error_of("experiment_id: \"a\"\nsac {\n  device: \"gpu\"\n}\n");
  EXPECT_NE(e.find("exp.txtpb:3:"), std::string::npos) << e;
  EXPECT_NE(e.find("sac.device"), std::string::npos) << e;
  EXPECT_NE(e.find("\"gpu\""), std::string::npos) << e;
}
