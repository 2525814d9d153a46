// The policy file of a checkpoint (common/policy_file.h): a policy written is read back field for
// field and acts the same; a missing, foreign, inconsistent or non-finite file is refused with an
// error naming the file and the fault.
#include <gtest/gtest.h>

#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>

#include "policy_file.h"

namespace {

namespace fs = std::filesystem;

farm::PolicyParams sample_policy() {
  farm::PolicyParams p;
  p.version = 4242;
  p.head = farm::PolicyHead::kGaussian;
  p.layout.sizes = {3, 5, 2};
  p.layout.activation = farm::Activation::kElu;
  p.params.resize(p.layout.num_params());
  for (size_t i = 0; i < p.params.size(); ++i) p.params[i] = 0.01f * float(i) - 0.2f;
  p.obs_mean = {0.5f, -1.f, 2.f};
  p.obs_std = {1.f, 0.25f, 3.f};
  p.log_std = {-0.5f, -1.5f};
  p.log_std_min = -5.f;
  p.log_std_max = 1.f;
  return p;
}

class PolicyFile : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("farm-policy-file-" + std::to_string(getpid()));
    fs::create_directories(dir_);
    path_ = (dir_ / farm::kPolicyFileName).string();
  }
  void TearDown() override { fs::remove_all(dir_); }
  // The error read_policy_file throws for the file at path_, or "" when it reads it.
  std::string error() {
    try {
      farm::read_policy_file(path_);
    } catch (const std::runtime_error& e) {
      return e.what();
    }
    return "";
  }
  fs::path dir_;
  std::string path_;
};

TEST_F(PolicyFile, ReadsBackWhatWasWritten) {
  const farm::PolicyParams p = sample_policy();
  farm::write_policy_file(path_, p);
  EXPECT_FALSE(fs::exists(path_ + ".tmp"));
  const farm::PolicyParams q = farm::read_policy_file(path_);
  EXPECT_EQ(q.version, 4242u);
  EXPECT_EQ(q.head, farm::PolicyHead::kGaussian);
  EXPECT_EQ(q.layout.sizes, p.layout.sizes);
  EXPECT_EQ(q.layout.activation, farm::Activation::kElu);
  EXPECT_EQ(q.params, p.params);
  EXPECT_EQ(q.obs_mean, p.obs_mean);
  EXPECT_EQ(q.obs_std, p.obs_std);
  EXPECT_EQ(q.log_std, p.log_std);
  EXPECT_EQ(q.log_std_min, -5.f);
  EXPECT_EQ(q.log_std_max, 1.f);
  // The policy read acts as the one written, bit for bit (its deterministic action).
  farm::Policy a(p), b(q);
  const float obs[3] = {0.3f, -0.7f, 1.9f};
  float act_a[2], act_b[2];
  std::mt19937_64 rng(5);
  a.act(obs, 1, rng, true, act_a, nullptr);
  b.act(obs, 1, rng, true, act_b, nullptr);
  EXPECT_EQ(act_a[0], act_b[0]);
  EXPECT_EQ(act_a[1], act_b[1]);
  EXPECT_NE(act_a[0], 0.f);
}

TEST_F(PolicyFile, AMissingFileIsNamed) { EXPECT_EQ(error(), "policy file " + path_ + ": does not exist"); }

TEST_F(PolicyFile, AFileThatIsNotOneIsRefused) {
  std::ofstream(path_) << "sac.pt\x01\xff\xff\xff garbage";
  EXPECT_EQ(error(), "policy file " + path_ + ": not a PolicyFile (policy_file.proto)");
  std::ofstream(path_, std::ios::trunc).close();  // empty: parses, but holds no policy
  EXPECT_NE(error().find("no head, activation or layer sizes"), std::string::npos) << error();
}

TEST_F(PolicyFile, InconsistentSizesAreRefused) {
  farm::PolicyParams p = sample_policy();
  p.params.pop_back();
  farm::write_policy_file(path_, p);
  EXPECT_NE(error().find("policy file " + path_ + ": policy params: expected 32 floats for layout 3-5-2 elu, got 31"),
            std::string::npos)
      << error();
  p = sample_policy();
  p.log_std = {0.f};
  farm::write_policy_file(path_, p);
  EXPECT_NE(error().find("gaussian head needs 2 log_std values, got 1"), std::string::npos) << error();
}

TEST_F(PolicyFile, NumbersThatAreNotFiniteAreRefused) {
  farm::PolicyParams p = sample_policy();
  p.params[7] = NAN;
  farm::write_policy_file(path_, p);
  EXPECT_NE(error().find("policy file " + path_ + ": parameters[7] is nan, not a finite number"), std::string::npos)
      << error();
  p = sample_policy();
  p.obs_mean[2] = INFINITY;
  farm::write_policy_file(path_, p);
  EXPECT_NE(error().find("obs_mean[2] is inf, not a finite number"), std::string::npos) << error();
}

}  // namespace
