// The rollout storage (learner/algorithms/storage/rollout_storage.h): its split and carry-over
// at a fit, the lag window and V-trace's log-probabilities, and its file, a PPO checkpoint's part.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <stdexcept>
#include <string>
#include <vector>

#include "paths.h"  // remove_tree: std::filesystem::remove_all crashes the GPU build
#include "rollout_storage.h"

using namespace farm;

TEST(RolloutStorage, TakesExactlyTheStepsAndCarriesTheTail) {
  // 2 envs x 3 steps, obs_dim 1 holding t*10+n; value(obs) = 0, so advantages are GAE of the
  // rewards alone; gamma 1, lambda 1: advantage = sum of the remaining rewards + bootstrap.
  const int T = 3, N = 2;
  std::vector<float> obs, next, act, rew, lp;
  std::vector<uint8_t> term(T * N, 0), trunc(T * N, 0);
  for (int t = 0; t < T; ++t)
    for (int n = 0; n < N; ++n) {
      obs.push_back(t * 10 + n);
      next.push_back((t + 1) * 10 + n);
      act.push_back(0.1f * n);
      rew.push_back(1.f);
      lp.push_back(-1.f - n);
    }
  RolloutStorage st(1, 1);
  st.add(T, N, obs.data(), act.data(), rew.data(), term.data(), trunc.data(), lp.data(), next.data(), 4);
  EXPECT_EQ(st.steps(), 6);
  auto zero = [](const float*, int64_t n) { return std::vector<float>(n, 0.f); };
  PpoSamples s;
  st.take(4, zero, 1.0, 1.0, 4, s);
  ASSERT_EQ(s.n, 4);
  EXPECT_EQ(st.steps(), 2);
  // Env 0's trajectory first (obs 0, 10, 20), then the first step of env 1.
  EXPECT_EQ(s.obs, (std::vector<float>{0, 10, 20, 1}));
  EXPECT_EQ(s.advantages, (std::vector<float>{3, 2, 1, 3}));
  EXPECT_EQ(s.current, (std::vector<uint8_t>{1, 1, 1, 1}));
  EXPECT_EQ(s.behaviour_log_prob[3], -2.f);
  // The carried tail is env 1's steps 1 and 2; fitted under a newer version it is not current.
  st.take(2, zero, 1.0, 1.0, 5, s);
  EXPECT_EQ(s.obs, (std::vector<float>{11, 21}));
  EXPECT_EQ(s.advantages, (std::vector<float>{2, 1}));
  EXPECT_EQ(s.current, (std::vector<uint8_t>{0, 0}));
  EXPECT_EQ(st.steps(), 0);
  EXPECT_THROW(st.take(1, zero, 1.0, 1.0, 5, s), std::invalid_argument);
}

TEST(RolloutStorage, DropsVersionsBeyondTheWindowAndCountsStepsByVersion) {
  // Three batches of 2 steps x 1 env made by versions 3, 4, 5; then the window moves to >= 4.
  RolloutStorage st(1, 1);
  const float obs[] = {1, 2}, next[] = {2, 3}, act[] = {0, 0}, rew[] = {1, 1}, lp[] = {-1, -1};
  const uint8_t no[] = {0, 0};
  for (uint64_t v : {3, 4, 5}) st.add(2, 1, obs, act, rew, no, no, lp, next, v);
  EXPECT_EQ(st.drop_older_than(4), 2);
  EXPECT_EQ(st.steps(), 4);
  auto zero = [](const float*, int64_t n) { return std::vector<float>(n, 0.f); };
  // V-trace with a target policy twice as likely as the behaviour one on every step.
  RolloutStorage::VTrace vt;
  int64_t asked = 0;
  vt.log_prob = [&](const float*, const float*, int64_t n) {
    asked += n;
    return std::vector<float>(n, -1.f + std::log(2.f));
  };
  PpoSamples s;
  std::map<uint64_t, int64_t> by_version;
  st.take(3, zero, 1.0, 1.0, 5, s, &vt, &by_version);
  EXPECT_EQ(asked, 4);  // every touched step's log-probability, in one call
  EXPECT_EQ(by_version, (std::map<uint64_t, int64_t>{{4, 2}, {5, 1}}));
  // Version 4's steps: ratio 2 truncated to 1, so GAE's 2, 1; version 5's own step: ratio 1.
  EXPECT_EQ(s.advantages, (std::vector<float>{2, 1, 2}));
  EXPECT_EQ(s.current, (std::vector<uint8_t>{0, 0, 1}));
  EXPECT_EQ(st.steps(), 1);
}

// The stored steps go to a file and back whole (a checkpoint's part): the same steps, versions,
// and what a fit takes from them; a file of other shapes, a truncated one or one whose header
// claims more than it holds is refused by name and leaves nothing stored.
TEST(RolloutStorage, SavesAndLoadsItsStepsAndRefusesABadFile) {
  RolloutStorage st(2, 1);
  const float obs[] = {1, 2, 3, 4, 5, 6, 7, 8}, next[] = {2, 3, 4, 5, 6, 7, 8, 9}, act[] = {0.1f, 0.2f, 0.3f, 0.4f};
  const float rew[] = {1, 2, 3, 4}, lp[] = {-1, -2, -3, -4};
  const uint8_t term[] = {0, 1, 0, 0}, trunc[] = {0, 0, 0, 1};
  st.add(2, 2, obs, act, rew, term, trunc, lp, next, 3);
  st.add(1, 2, obs, act, rew, term, trunc, lp, next, 4);
  const auto dir = std::filesystem::temp_directory_path() / ("rollouts_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const std::string file = (dir / "rollouts.bin").string();
  st.save(file);
  RolloutStorage back(2, 1);
  back.load(file);
  EXPECT_EQ(back.steps(), 6);
  back.shift_versions(10);
  auto zero = [](const float*, int64_t n) { return std::vector<float>(n, 0.f); };
  PpoSamples a, b;
  std::map<uint64_t, int64_t> va, vb;
  st.take(6, zero, 0.9, 0.8, 4, a, nullptr, &va);
  back.take(6, zero, 0.9, 0.8, 14, b, nullptr, &vb);
  EXPECT_EQ(b.obs, a.obs);
  EXPECT_EQ(b.actions, a.actions);
  EXPECT_EQ(b.advantages, a.advantages);
  EXPECT_EQ(b.behaviour_log_prob, a.behaviour_log_prob);
  EXPECT_EQ(b.current, a.current);
  EXPECT_EQ(va, (std::map<uint64_t, int64_t>{{3, 4}, {4, 2}}));
  EXPECT_EQ(vb, (std::map<uint64_t, int64_t>{{13, 4}, {14, 2}}));

  auto refused = [&](RolloutStorage& s, const std::string& f, const std::string& why) {
    try {
      s.load(f);
      ADD_FAILURE() << "loaded " << f << ", expected: " << why;
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find(why), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(f), std::string::npos) << e.what();
    }
    EXPECT_EQ(s.steps(), 0);
  };
  RolloutStorage other(3, 1);
  refused(other, file, "file has obs 2, act 1, expected obs 3, act 1");
  std::string bytes;
  {
    std::ifstream in(file, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), {});
  }
  auto write = [&](const std::string& b) {
    std::ofstream out(file, std::ios::binary | std::ios::trunc);
    out << b;
  };
  RolloutStorage again(2, 1);
  again.load(file);  // leaves steps stored: each refusal below must clear them
  write(bytes.substr(0, bytes.size() - 3));
  refused(again, file, "past what the file holds");
  std::string huge = bytes;
  const int64_t many = int64_t(1) << 40;
  std::memcpy(&huge[16], &many, sizeof many);  // the header's trajectory count
  write(huge);
  refused(again, file, "inconsistent header");
  write("not a rollout file at all, long enough for a header");
  refused(again, file, "bad magic");
  farm::remove_tree(dir.string());
}
