// The A1 of the MushroomRL paper written as a task of terms (deploy/configs/a1_terms_ppo.txtpb) against the
// hand-written task "a1" (deploy/configs/a1_ppo.txtpb): from the same seeds and the same actions,
// over thousands of steps and many episodes, the same observations and rewards to float rounding,
// and the same terminations and truncations on the same steps.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "config.h"
#include "task.h"
#include "task_specs.h"

namespace farm::robots {
namespace {

const std::string kConfigs = std::string(FARM_SOURCE_DIR) + "/deploy/configs";

// Float rounding of values computed in double in a different order, then cast to float.
bool close(double a, double b) { return std::abs(a - b) <= 2e-5 * std::max(1.0, std::abs(a)); }

int index_of(const std::vector<std::string>& names, const std::string& name) {
  const auto it = std::find(names.begin(), names.end(), name);
  return it == names.end() ? -1 : int(it - names.begin());
}

TEST(TermsA1, TheA1AsTermsIsTheHandWrittenA1) {
  const auto hand_cfg = load_config_file(kConfigs + "/a1_ppo.txtpb");
  const auto terms_cfg = load_config_file(kConfigs + "/a1_terms_ppo.txtpb");
  ASSERT_EQ(hand_cfg.task().name(), "a1");
  ASSERT_EQ(terms_cfg.task().name(), "terms");
  const auto hand = make_task(hand_cfg.task());
  const auto terms = make_task(terms_cfg.task());
  const int obs_dim = hand->spec().obs_dim, act_dim = hand->spec().act_dim;
  ASSERT_EQ(terms->spec().obs_dim, obs_dim);
  ASSERT_EQ(terms->spec().act_dim, act_dim);
  const auto& hm = hand->spec().metric_names;
  const auto& tm = terms->spec().metric_names;
  const int h_track = index_of(hm, "tracking_lin"), h_fell = index_of(hm, "fell");
  const int t_track = index_of(tm, "mean.lin_vel_tracking"), t_fell = index_of(tm, "terminated");
  ASSERT_TRUE(h_track >= 0 && h_fell >= 0 && t_track >= 0 && t_fell >= 0);

  auto hs = hand->make_state(), ts = terms->make_state();
  std::vector<float> ho(obs_dim), to(obs_dim), a(act_dim), hmet(hm.size()), tmet(tm.size());
  std::mt19937_64 rng(2024);
  std::normal_distribution<float> calm(0.f, 0.1f);
  std::uniform_real_distribution<float> wild(-1.3f, 1.3f);  // past the box too: both clamp
  uint64_t seed = 1000;
  int episodes = 0, terminated = 0, truncated = 0, positive = 0, step_in_episode = 0;
  double max_obs_diff = 0, max_reward_diff = 0;
  const auto reset = [&] {
    hand->reset(*hs, seed, ho.data());
    terms->reset(*ts, seed, to.data());
    ++seed;
    step_in_episode = 0;
    for (int i = 0; i < obs_dim; ++i) {
      ASSERT_TRUE(close(ho[i], to[i])) << "reset of seed " << seed - 1 << ", observation " << i << ": " << ho[i]
                                       << " (a1) vs " << to[i] << " (terms)";
      max_obs_diff = std::max(max_obs_diff, double(std::abs(ho[i] - to[i])));
    }
  };
  reset();
  const int kSteps = 8000;
  for (int step = 0; step < kSteps; ++step) {
    // Every other episode near the default pose (it stands, is pushed, and runs into its time
    // limit); the others flail with actions across and past the box (falls, contacts).
    const bool calm_episode = episodes % 2 == 0;
    for (auto& x : a) x = calm_episode ? calm(rng) : wild(rng);
    const StepResult hr = hand->step(*hs, a.data(), ho.data());
    const StepResult tr = terms->step(*ts, a.data(), to.data());
    ++step_in_episode;
    ASSERT_EQ(hr.terminated, tr.terminated) << "step " << step << " (episode step " << step_in_episode << ")";
    ASSERT_EQ(hr.truncated, tr.truncated) << "step " << step;
    ASSERT_TRUE(close(hr.reward, tr.reward))
        << "step " << step << ": reward " << hr.reward << " (a1) vs " << tr.reward << " (terms)";
    max_reward_diff = std::max(max_reward_diff, double(std::abs(hr.reward - tr.reward)));
    positive += hr.reward > 0;
    for (int i = 0; i < obs_dim; ++i) {
      ASSERT_TRUE(close(ho[i], to[i])) << "step " << step << " (episode step " << step_in_episode << "), observation "
                                       << i << ": " << ho[i] << " (a1) vs " << to[i] << " (terms)";
      max_obs_diff = std::max(max_obs_diff, double(std::abs(ho[i] - to[i])));
    }
    if (hr.terminated || hr.truncated) {
      hand->episode_metrics(*hs, hmet.data());
      terms->episode_metrics(*ts, tmet.data());
      EXPECT_TRUE(close(hmet[h_track], tmet[t_track])) << hmet[h_track] << " vs " << tmet[t_track];
      EXPECT_EQ(hmet[h_fell], tmet[t_fell]);
      terminated += hr.terminated;
      truncated += hr.truncated;
      ++episodes;
      reset();
    }
  }
  // The comparison covered what it is meant to: falls, time-outs (with a push at 15 s), rewards.
  EXPECT_GE(terminated, 5);
  EXPECT_GE(truncated, 1);
  EXPECT_GT(positive, kSteps / 10);
  std::printf(
      "%d steps, %d episodes (%d terminated, %d truncated); largest difference: observation %.3g, reward %.3g\n",
      kSteps, episodes, terminated, truncated, max_obs_diff, max_reward_diff);
}

}  // namespace
}  // namespace farm::robots
