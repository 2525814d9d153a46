#include "replay_buffer.h"

#include "device_replay.h"
#include "rng_state.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

namespace farm {
namespace {

constexpr int kObs = 3, kAct = 2;

// Transition k is recognizable from any of its fields: obs = (k, k+0.25, k+0.5), action = (-k,
// -k-0.5), reward = 10k, next_obs = obs + 1000, terminated when k % 3 == 0.
struct Rows {
  std::vector<float> obs, act, rew, next_obs;
  std::vector<uint8_t> term;
  void push(int k) {
    for (int j = 0; j < kObs; ++j) obs.push_back(k + 0.25f * j);
    for (int j = 0; j < kAct; ++j) act.push_back(-k - 0.5f * j);
    rew.push_back(10.f * k);
    term.push_back(k % 3 == 0);
    for (int j = 0; j < kObs; ++j) next_obs.push_back(k + 0.25f * j + 1000.f);
  }
};

Rows make_rows(int from, int to) {
  Rows r;
  for (int k = from; k < to; ++k) r.push(k);
  return r;
}

void add_one_by_one(ReplayBuffer& b, int from, int to) {
  for (int k = from; k < to; ++k) {
    Rows r = make_rows(k, k + 1);
    b.add(r.obs.data(), r.act.data(), r.rew[0], r.term[0], r.next_obs.data());
  }
}

void add_block(ReplayBuffer& b, int from, int to) {
  Rows r = make_rows(from, to);
  b.add_n(to - from, r.obs.data(), r.act.data(), r.rew.data(), r.term.data(), r.next_obs.data());
}

// Every sampled row must be one whole stored transition; returns the ids seen.
std::multiset<int> check_rows(const SampledBatch& s) {
  std::multiset<int> ids;
  const int64_t n = s.obs.size(0);
  EXPECT_EQ(s.obs.sizes(), (std::vector<int64_t>{n, kObs}));
  EXPECT_EQ(s.actions.sizes(), (std::vector<int64_t>{n, kAct}));
  EXPECT_EQ(s.rewards.sizes(), (std::vector<int64_t>{n}));
  EXPECT_EQ(s.terminated.sizes(), (std::vector<int64_t>{n}));
  EXPECT_EQ(s.next_obs.sizes(), (std::vector<int64_t>{n, kObs}));
  auto o = s.obs.accessor<float, 2>(), a = s.actions.accessor<float, 2>(), no = s.next_obs.accessor<float, 2>();
  auto r = s.rewards.accessor<float, 1>(), t = s.terminated.accessor<float, 1>();
  for (int64_t i = 0; i < n; ++i) {
    const int k = int(o[i][0]);
    for (int j = 0; j < kObs; ++j) {
      EXPECT_EQ(o[i][j], k + 0.25f * j);
      EXPECT_EQ(no[i][j], k + 0.25f * j + 1000.f);
    }
    for (int j = 0; j < kAct; ++j) EXPECT_EQ(a[i][j], -k - 0.5f * j);
    EXPECT_EQ(r[i], 10.f * k);
    EXPECT_EQ(t[i], k % 3 == 0 ? 1.f : 0.f);
    ids.insert(k);
  }
  return ids;
}

std::string temp_file(const std::string& name) {
  return (std::filesystem::temp_directory_path() / (name + "_" + std::to_string(::getpid()) + ".bin")).string();
}

TEST(ReplayBuffer, CountsBeforeAndAfterWrap) {
  ReplayBuffer b(10, kObs, kAct);
  EXPECT_EQ(b.size(), 0);
  EXPECT_EQ(b.capacity(), 10);
  add_one_by_one(b, 0, 7);
  EXPECT_EQ(b.size(), 7);
  EXPECT_EQ(b.total_added(), 7);
  add_block(b, 7, 12);
  EXPECT_EQ(b.size(), 10);
  EXPECT_EQ(b.total_added(), 12);
  add_one_by_one(b, 12, 25);
  EXPECT_EQ(b.size(), 10);
  EXPECT_EQ(b.total_added(), 25);
}

TEST(ReplayBuffer, SamplesAreStoredTransitions) {
  ReplayBuffer b(64, kObs, kAct);
  add_block(b, 0, 40);
  std::mt19937_64 rng(7);
  const auto ids = check_rows(b.sample(4096, rng));
  for (int id : ids) EXPECT_TRUE(id >= 0 && id < 40) << id;
  // 4096 uniform draws over 40 rows miss one with probability ~40 * exp(-102): all must show up.
  EXPECT_EQ(std::set<int>(ids.begin(), ids.end()).size(), 40u);
}

// After wrapping, exactly the newest `capacity` transitions remain, whichever add path filled it.
TEST(ReplayBuffer, WraparoundKeepsNewestRows) {
  for (int mode = 0; mode < 3; ++mode) {
    ReplayBuffer b(16, kObs, kAct);
    if (mode == 0) add_one_by_one(b, 0, 45);
    if (mode == 1) {  // blocks that straddle the end of the ring
      add_block(b, 0, 11);
      add_block(b, 11, 30);
      add_block(b, 30, 45);
    }
    if (mode == 2) add_block(b, 0, 45);  // one block larger than the capacity
    EXPECT_EQ(b.size(), 16);
    EXPECT_EQ(b.total_added(), 45);
    std::mt19937_64 rng(mode);
    const auto ids = check_rows(b.sample(2048, rng));
    const std::set<int> seen(ids.begin(), ids.end());
    std::set<int> want;
    for (int k = 45 - 16; k < 45; ++k) want.insert(k);
    EXPECT_EQ(seen, want) << "mode " << mode;
  }
}

TEST(ReplayBuffer, SampleIsDeterministicForASeed) {
  ReplayBuffer b(32, kObs, kAct);
  add_block(b, 0, 32);
  std::mt19937_64 r1(3), r2(3);
  const auto s1 = b.sample(64, r1), s2 = b.sample(64, r2);
  EXPECT_TRUE(torch::equal(s1.obs, s2.obs));
  EXPECT_TRUE(torch::equal(s1.next_obs, s2.next_obs));
}

TEST(ReplayBuffer, SampleFromEmptyThrows) {
  ReplayBuffer b(4, kObs, kAct);
  std::mt19937_64 rng(1);
  EXPECT_THROW(b.sample(8, rng), std::logic_error);
}

TEST(ReplayBuffer, SaveLoadRoundTrip) {
  for (int n : {5, 23}) {  // partly filled, and wrapped
    ReplayBuffer b(16, kObs, kAct);
    add_block(b, 0, n);
    const std::string file = temp_file("rb_roundtrip");
    b.save(file);
    ReplayBuffer c(16, kObs, kAct);
    add_block(c, 500, 503);  // whatever was there is replaced
    c.load(file);
    std::remove(file.c_str());
    EXPECT_EQ(c.size(), b.size());
    EXPECT_EQ(c.total_added(), b.total_added());
    std::mt19937_64 r1(11), r2(11);
    const auto s1 = b.sample(256, r1), s2 = c.sample(256, r2);
    EXPECT_TRUE(torch::equal(s1.obs, s2.obs));
    EXPECT_TRUE(torch::equal(s1.actions, s2.actions));
    EXPECT_TRUE(torch::equal(s1.rewards, s2.rewards));
    EXPECT_TRUE(torch::equal(s1.terminated, s2.terminated));
    EXPECT_TRUE(torch::equal(s1.next_obs, s2.next_obs));
    // The ring position survives too: the next adds overwrite the same (oldest) rows in both.
    add_block(b, 100, 110);
    add_block(c, 100, 110);
    std::mt19937_64 r3(12), r4(12);
    EXPECT_TRUE(torch::equal(b.sample(256, r3).obs, c.sample(256, r4).obs));
  }
}

TEST(ReplayBuffer, LoadRejectsMismatchNamingFile) {
  ReplayBuffer b(16, kObs, kAct);
  add_block(b, 0, 9);
  const std::string file = temp_file("rb_mismatch");
  b.save(file);
  auto expect_error = [&](ReplayBuffer& other, const std::string& what) {
    try {
      other.load(file);
      ADD_FAILURE() << "no error for " << what;
    } catch (const std::runtime_error& e) {
      const std::string msg = e.what();
      EXPECT_NE(msg.find(file), std::string::npos) << msg;
      EXPECT_NE(msg.find(what), std::string::npos) << msg;
    }
    EXPECT_EQ(other.size(), 0);
  };
  ReplayBuffer wrong_obs(16, kObs + 1, kAct), wrong_act(16, kObs, kAct + 1), wrong_cap(17, kObs, kAct);
  expect_error(wrong_obs, "obs_dim 3");
  expect_error(wrong_act, "act_dim 2");
  expect_error(wrong_cap, "capacity 16");

  // A truncated file is caught before any row is read.
  std::filesystem::resize_file(file, std::filesystem::file_size(file) - 4);
  ReplayBuffer same(16, kObs, kAct);
  expect_error(same, "bytes");
  std::remove(file.c_str());

  ReplayBuffer missing(16, kObs, kAct);
  EXPECT_THROW(missing.load(file), std::runtime_error);
}

// Multi-step rows keep their horizon through sampling and a save/load; one-step adds read as 1.
TEST(ReplayBuffer, HorizonIsStoredSampledAndSaved) {
  ReplayBuffer b(8, 1, 1);
  const float obs[3] = {0, 1, 2}, act[3] = {0, 0, 0}, rew[3] = {0, 1, 2}, next[3] = {10, 11, 12};
  const uint8_t term[3] = {0, 0, 1};
  const float horizon[3] = {3, 2, 1};
  b.add_n(3, obs, act, rew, term, next, horizon);
  b.add(obs, act, 5.f, false, next);  // one-step row: obs 0, reward 5
  auto check = [](const SampledBatch& s) {
    for (int i = 0; i < s.obs.size(0); ++i) {
      const float r = s.rewards[i].item<float>(), h = s.horizon[i].item<float>();
      EXPECT_FLOAT_EQ(h, r == 5.f ? 1.f : 3.f - r) << "row with reward " << r;
    }
  };
  std::mt19937_64 rng(5);
  check(b.sample(64, rng));
  const std::string file = temp_file("rb_horizon");
  b.save(file);
  ReplayBuffer c(8, 1, 1);
  c.load(file);
  check(c.sample(64, rng));
  // A file of the earlier format (no horizon column) is refused by name, not misread.
  {
    std::fstream f(file, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(6);
    f.write("01", 2);
  }
  ReplayBuffer d(8, 1, 1);
  try {
    d.load(file);
    ADD_FAILURE() << "an 01 file loaded";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("format 01"), std::string::npos) << e.what();
  }
  std::remove(file.c_str());
}

// DeviceReplay on the CPU here (and on a GPU where there is one): the copy holds the host
// buffer's rows at the host's ring positions through blocks that straddle the ring's end and one
// larger than the capacity, and rebuilds them from the host buffer.
std::vector<torch::Device> replay_devices() {
  std::vector<torch::Device> d{torch::kCPU};
  if (torch::cuda::is_available()) d.emplace_back(torch::kCUDA, 0);
  return d;
}

void add_block(ReplayBuffer& host, DeviceReplay& dev, int from, int to) {
  Rows r = make_rows(from, to);
  host.add_n(to - from, r.obs.data(), r.act.data(), r.rew.data(), r.term.data(), r.next_obs.data());
  dev.add_n(to - from, r.obs.data(), r.act.data(), r.rew.data(), r.term.data(), r.next_obs.data());
}

// Row i of the copy against row i of the host buffer (obs | action | reward | terminated | next_obs).
void expect_same_rows(const ReplayBuffer& host, const DeviceReplay& dev) {
  ASSERT_EQ(dev.size(), host.size());
  EXPECT_EQ(dev.fill().cpu().item<int64_t>(), host.size());
  const SampledBatch s = host.stored();
  const auto want = torch::cat({s.obs, s.actions, s.rewards.unsqueeze(1), s.terminated.unsqueeze(1), s.next_obs}, 1);
  EXPECT_TRUE(torch::equal(dev.rows().narrow(0, 0, dev.size()).cpu(), want));
}

TEST(DeviceReplay, KeepsTheHostRowsAtTheirPositions) {
  for (const auto& device : replay_devices()) {
    SCOPED_TRACE(device.str());
    ReplayBuffer host(16, kObs, kAct);
    DeviceReplay dev(16, kObs, kAct, device, 0.99);
    EXPECT_EQ(dev.width(), 2 * kObs + kAct + 2);
    add_block(host, dev, 0, 11);
    expect_same_rows(host, dev);
    add_block(host, dev, 11, 30);  // wraps
    expect_same_rows(host, dev);
    add_block(host, dev, 30, 75);  // more than the capacity in one block
    expect_same_rows(host, dev);
    add_block(host, dev, 75, 78);
    expect_same_rows(host, dev);
    EXPECT_EQ(host.next_row(), 78 % 16);

    DeviceReplay rebuilt(16, kObs, kAct, device, 0.99);
    rebuilt.load_from(host);
    expect_same_rows(host, rebuilt);
    // The next rows land where the host's do.
    add_block(host, rebuilt, 78, 83);
    expect_same_rows(host, rebuilt);
    EXPECT_THROW(DeviceReplay(8, kObs, kAct, device, 0.99).load_from(host), std::invalid_argument);
  }
}

// sac.n_step: gamma * (1 - fold_horizon(t, h)) is gamma^h * (1 - t); horizon 1 is t itself. The
// device copy keeps multi-step rows so folded, from add_n and from load_from alike.
TEST(DeviceReplay, FoldsEachRowsHorizonIntoItsTerminatedFlag) {
  for (const float t : {0.f, 1.f}) {
    EXPECT_EQ(fold_horizon(t, 1.f, 0.9), t);
    for (const float h : {2.f, 3.f, 5.f})
      EXPECT_NEAR(0.9 * (1.0 - fold_horizon(t, h, 0.9)), std::pow(0.9, h) * (1.0 - t), 1e-6) << t << " " << h;
  }
  for (const auto& device : replay_devices()) {
    SCOPED_TRACE(device.str());
    ReplayBuffer host(16, kObs, kAct);
    DeviceReplay dev(16, kObs, kAct, device, 0.9);
    Rows r = make_rows(0, 12);
    std::vector<float> horizon(12);
    for (int k = 0; k < 12; ++k) horizon[k] = float(1 + k % 4);
    host.add_n(12, r.obs.data(), r.act.data(), r.rew.data(), r.term.data(), r.next_obs.data(), horizon.data());
    dev.add_n(12, r.obs.data(), r.act.data(), r.rew.data(), r.term.data(), r.next_obs.data(), horizon.data());
    DeviceReplay rebuilt(16, kObs, kAct, device, 0.9);
    rebuilt.load_from(host);
    for (const DeviceReplay* d : {&dev, &rebuilt}) {
      const auto done = d->rows().narrow(0, 0, 12).select(1, kObs + kAct + 1).cpu();
      for (int k = 0; k < 12; ++k) {
        const double want = 1.0 - std::pow(0.9, horizon[k] - 1) * (1.0 - r.term[k]);
        EXPECT_NEAR(done[k].item<float>(), want, 1e-6) << "row " << k;
      }
    }
    // Without horizons the column is the flag.
    DeviceReplay plain(16, kObs, kAct, device, 0.9);
    plain.add_n(12, r.obs.data(), r.act.data(), r.rew.data(), r.term.data(), r.next_obs.data());
    const auto flags = plain.rows().narrow(0, 0, 12).select(1, kObs + kAct + 1).cpu();
    for (int k = 0; k < 12; ++k) EXPECT_EQ(flags[k].item<float>(), float(r.term[k])) << "row " << k;
  }
}

// Drawn rows are whole stored transitions, cover every stored row, only stored rows (the ring
// not yet full: rows past size() are never drawn), and follow torch's generator.
TEST(DeviceReplay, SamplesStoredRowsUniformly) {
  for (const auto& device : replay_devices()) {
    SCOPED_TRACE(device.str());
    ReplayBuffer host(64, kObs, kAct);
    DeviceReplay dev(64, kObs, kAct, device, 0.99);
    EXPECT_THROW(dev.sample(4), std::logic_error);
    add_block(host, dev, 0, 20);
    torch::manual_seed(3);
    const SampledBatch b = dev.sample(4000);
    SampledBatch on_host{b.obs.cpu(), b.actions.cpu(), b.rewards.cpu(), b.terminated.cpu(), b.next_obs.cpu(), {}};
    const auto ids = check_rows(on_host);
    std::set<int> want;
    for (int k = 0; k < 20; ++k) want.insert(k);
    EXPECT_EQ(std::set<int>(ids.begin(), ids.end()), want);
    for (int k = 0; k < 20; ++k) {  // 200 expected each: a binomial's 6 sigma is 85
      EXPECT_GT(ids.count(k), 115u) << k;
      EXPECT_LT(ids.count(k), 285u) << k;
    }
    // The indices are floor(u * size) of torch's uniform draw, the largest u included.
    const auto u =
        torch::tensor({0.0, 0.049999, 0.05, 0.999999999}, torch::TensorOptions().dtype(torch::kDouble)).to(device);
    EXPECT_TRUE(torch::equal(dev.indices(u).cpu(), torch::tensor({0, 0, 1, 19}, torch::kLong)));
    torch::manual_seed(3);
    EXPECT_TRUE(torch::equal(dev.sample(4000).obs.cpu(), b.obs.cpu()));
  }
}

// A resumed learner draws what the uninterrupted one would have drawn next: the replay sampler's
// generator and LibTorch's CPU generator go through the checkpoint manifest and come back.
TEST(RngState, RoundTripsThroughTheManifest) {
  std::mt19937_64 sampler(5);
  torch::manual_seed(9);
  sampler();
  torch::rand({3});
  config::CheckpointManifest m;
  rng_to_manifest(&sampler, m);
  ASSERT_TRUE(m.has_sampler_rng_state());
  ASSERT_FALSE(m.torch_rng_state().empty());
  const uint64_t next = sampler();
  const torch::Tensor next_t = torch::rand({4});

  std::mt19937_64 other(123);
  torch::manual_seed(77);  // as a fresh learner seeds itself from the experiment
  rng_from_manifest(m, &other);
  EXPECT_EQ(other(), next);
  EXPECT_TRUE(torch::equal(torch::rand({4}), next_t));

  config::CheckpointManifest bad = m;
  bad.set_sampler_rng_state("not a generator state");
  EXPECT_THROW(rng_from_manifest(bad, &other), std::runtime_error);
}

}  // namespace
}  // namespace farm
