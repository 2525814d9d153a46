// sac.max_step_scale: the rule that picks the step scale, SAC's adapter keeping the seed's step on
// the CPU, and the replay driver growing and shrinking the step against the env steps a farm
// reports (learner/algorithms/off_policy.cpp, off_policy_algorithm.cpp). And the driver's side of
// updates that are still running on a GPU when update_n returns: their figures are checked before
// any weights leave the learner.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <deque>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include <unistd.h>

#include "algorithm.h"
#include "config.h"
#include "meter.h"
#include "off_policy.h"

namespace farm {
namespace {

TEST(SacStepScale, FollowsTheDataWithAMarginAndBounds) {
  struct Case {
    int current;
    double r;
    int most, want;
  } cases[] = {
      // clang-format off
      // Up to the power of 2 nearest r on a log scale: s for r from s / sqrt(2) on; within `most`.
      {1, 1.0, 4, 1}, {1, 1.41, 4, 1}, {1, 1.42, 4, 2}, {1, 2.8, 4, 2}, {1, 2.9, 4, 4}, {1, 9.0, 4, 4},
      {1, 9.0, 6, 4}, {1, 40.0, 64, 32}, {1, 46.0, 64, 64}, {1, 5.0, 1, 1},
      // Down only below 0.8 s / sqrt(2): x4 holds where r is 3-4 (a floor took x2 there).
      {4, 3.1, 4, 4}, {4, 2.3, 4, 4}, {4, 2.2, 4, 2}, {4, 0.9, 4, 1}, {2, 1.2, 4, 2}, {2, 1.1, 4, 1},
      {4, 0.0, 4, 1}, {8, 50.0, 4, 4},  // none, and past most
      // clang-format on
  };
  for (const auto& c : cases)
    EXPECT_EQ(next_step_scale(c.current, c.r, c.most), c.want)
        << "current " << c.current << ", r " << c.r << ", most " << c.most;
}

// What the replay driver sees of the farm: env steps as the test sets them, the log kept.
class StepScaleFarm final : public Farm {
 public:
  void publish(const PolicyParams&, uint32_t) override { ++published_; }
  std::vector<LiveWorker> live_workers() const override { return {}; }
  double first_worker_heard() const override { return 0; }
  FarmFigures figures() const override { return {}; }
  uint64_t env_steps() const override { return env_steps_; }
  double elapsed() const override { return 0; }
  bool ask_evaluation(const PolicyParams&, const EvalAsk&) override { return true; }
  void record_evaluation(const EvalReport&, uint64_t, int64_t, double) override {}
  void log(const std::string& line) const override { lines_.push_back(line); }
  void csv_row(const std::string&) override {}
  uint64_t env_steps_ = 0;
  int published_ = 0;
  mutable std::vector<std::string> lines_;
};

// SAC's adapter as it is, but with what it would do on a GPU, so that the driver's side runs here:
// the step scale (its own keeps the seed's step on the CPU), and, with `held` > 0, update_n
// returning before the figures of its last `held` updates are in (they come with the next call or
// finish_updates(), as a CUDA graph's queued replays do). Update `nan_at` (counted from 1) has a
// critic loss of NaN.
class StepScaleOnAnyDevice final : public OffPolicy {
 public:
  StepScaleOnAnyDevice(std::unique_ptr<OffPolicy> sac, int most, int held = 0, int64_t nan_at = 0)
      : sac_(std::move(sac)), most_(most), held_(held), nan_at_(nan_at) {}
  std::string name() const override { return sac_->name(); }
  OffPolicyStats update(const SampledBatch& b) override { return sac_->update(b); }
  std::vector<OffPolicyStats> update_n(int n, const std::function<SampledBatch()>& next) override {
    for (const OffPolicyStats& f : sac_->update_n(n, next)) {
      in_flight_.push_back(f);
      if (++made_ == nan_at_) in_flight_.back().critic_loss = NAN;
    }
    std::vector<OffPolicyStats> out;
    while (int(in_flight_.size()) > held_) {
      out.push_back(in_flight_.front());
      in_flight_.pop_front();
    }
    return out;
  }
  int64_t updates_in_flight() const override { return int64_t(in_flight_.size()); }
  std::vector<OffPolicyStats> finish_updates() override {
    std::vector<OffPolicyStats> out(in_flight_.begin(), in_flight_.end());
    in_flight_.clear();
    return out;
  }
  PolicyParams export_policy(uint64_t v) const override { return sac_->export_policy(v); }
  int64_t updates() const override { return sac_->updates(); }
  void save(const std::string& dir) const override { sac_->save(dir); }
  void load(const std::string& dir) override { sac_->load(dir); }
  int batch_size() const override { return sac_->batch_size(); }
  int64_t buffer_size() const override { return sac_->buffer_size(); }
  int64_t learning_starts() const override { return sac_->learning_starts(); }
  double max_updates_per_step() const override { return sac_->max_updates_per_step(); }
  int publish_every_updates() const override { return sac_->publish_every_updates(); }
  int max_step_scale() const override { return most_; }
  int step_scale() const override { return sac_->step_scale(); }
  void set_step_scale(int s) override { sac_->set_step_scale(s); }
  double gamma() const override { return sac_->gamma(); }
  std::string describe() const override { return sac_->describe(); }

 private:
  std::unique_ptr<OffPolicy> sac_;
  int most_, held_;
  int64_t nan_at_, made_ = 0;
  std::deque<OffPolicyStats> in_flight_;
};

config::ExperimentConfig step_scale_config() {
  return parse_config_text(
      "experiment_id: \"step_scale\" algorithm: \"sac\" eval { every_seconds: 1000 }\n"
      "sac { hidden: [8, 8] batch_size: 16 learning_starts: 64 max_updates_per_step: 1 max_step_scale: 4 }\n",
      "step_scale.txtpb");
}

robots::TaskSpec step_scale_spec() {
  robots::TaskSpec spec;
  spec.name = "step_scale";
  spec.obs_dim = 3;
  spec.act_dim = 1;
  spec.max_episode_steps = 100;
  return spec;
}

// One env step of `rows` envs (step_scale_spec's shapes), as a batch the driver takes.
struct OneStep {
  explicit OneStep(int rows) : truncated(rows, 0) {
    t.n = rows;
    t.obs.assign(rows * 3, 0.5f);
    t.actions.assign(rows, 0.1f);
    t.rewards.assign(rows, 1.f);
    t.next_obs.assign(rows * 3, 0.4f);
    t.terminated.assign(rows, 0);
    batch.num_steps = 1;
    batch.num_envs = rows;
    batch.truncated = truncated.data();
    batch.rows = &t;
  }
  Transitions t;
  std::vector<uint8_t> truncated;
  Batch batch;
};

// On the CPU a batch four times as large costs nearly four times the time, so SAC's adapter keeps
// the seed's step there whatever sac.max_step_scale says, and its start line says so.
TEST(SacStepScale, TheCpuKeepsTheSeedsStep) {
  auto cfg = step_scale_config();
  cfg.mutable_sac()->set_device("cpu");
  const auto sac = make_sac(cfg, step_scale_spec());
  EXPECT_EQ(sac->max_step_scale(), 1);
  EXPECT_NE(sac->describe().find("the seed's step (sac.max_step_scale is for a GPU learner)"), std::string::npos)
      << sac->describe();
  sac->set_step_scale(4);  // the driver never asks it here; if asked, the batch follows
  EXPECT_EQ(sac->batch_size(), 64);
}

// sac.n_step reaches the replay driver (which folds the rows it stores, fold_n_step) and the
// start line; 1, the seed's, says nothing.
TEST(SacStepScale, MultiStepReturnsAreTheAdaptersToAsk) {
  auto cfg = step_scale_config();
  EXPECT_EQ(make_sac(cfg, step_scale_spec())->n_step(), 1);
  EXPECT_EQ(make_sac(cfg, step_scale_spec())->describe().find("-step returns"), std::string::npos);
  cfg.mutable_sac()->set_n_step(3);
  const auto sac = make_sac(cfg, step_scale_spec());
  EXPECT_EQ(sac->n_step(), 3);
  EXPECT_NE(sac->describe().find(", 3-step returns"), std::string::npos) << sac->describe();
}

// The driver's side of sac.max_step_scale: while the env steps received allow far more updates
// than it makes, the step grows to the configured most; once no data comes, it falls back.
TEST(SacStepScale, DriverScalesWhileDataOutrunUpdatesAndBack) {
  const auto cfg = step_scale_config();
  const auto spec = step_scale_spec();
  auto algo = make_off_policy_algorithm(std::make_unique<StepScaleOnAnyDevice>(make_sac(cfg, spec), 4), cfg, spec);
  StepScaleFarm farm;
  algo->start(farm);
  ASSERT_TRUE(algo->take(OneStep(256).batch));

  auto run_for = [&](double seconds, uint64_t steps_per_pass) {
    const double end = now_seconds() + seconds;
    while (now_seconds() < end) {
      farm.env_steps_ += steps_per_pass;
      algo->train(farm, true);
    }
  };
  auto logged = [&](const std::string& what) {
    return std::any_of(farm.lines_.begin(), farm.lines_.end(),
                       [&](const std::string& l) { return l.find(what) != std::string::npos; });
  };
  run_for(2.5, 1000000);  // data for a million updates a pass: the step grows to x4
  EXPECT_TRUE(logged("sac step x4 from update")) << ::testing::PrintToString(farm.lines_);
  EXPECT_TRUE(logged("batch 64, learning rates x2.00")) << ::testing::PrintToString(farm.lines_);
  EXPECT_FALSE(logged("sac step x8"));
  const size_t grown = farm.lines_.size();
  run_for(2.5, 0);  // no more data; the backlog keeps it updating, but the data allow nothing new
  ASSERT_GT(farm.lines_.size(), grown) << ::testing::PrintToString(farm.lines_);
  EXPECT_NE(farm.lines_.back().find("sac step x1 from update"), std::string::npos) << farm.lines_.back();
  EXPECT_NE(farm.lines_.back().find("batch 16, learning rates x1.00"), std::string::npos) << farm.lines_.back();
}

// The replay driver over SAC whose groups return with their last 3 updates' figures still out (as
// on a GPU), update `nan_at` NaN, publishing every `publish_every` updates; started, with data for
// a million updates and one batch taken.
std::unique_ptr<Algorithm> driver_with_updates_held(int64_t nan_at, int publish_every, StepScaleFarm& farm) {
  auto cfg = step_scale_config();
  cfg.mutable_sac()->set_max_step_scale(1);
  cfg.mutable_sac()->set_publish_every_updates(publish_every);
  const auto spec = step_scale_spec();
  auto algo =
      make_off_policy_algorithm(std::make_unique<StepScaleOnAnyDevice>(make_sac(cfg, spec), 1, 3, nan_at), cfg, spec);
  farm.env_steps_ = 1000000;
  algo->start(farm);
  EXPECT_TRUE(algo->take(OneStep(128).batch));
  return algo;
}

// A group of updates may return while its last ones still run on the GPU. A diverged update among
// those must stop the run before the next publish sends its weights to the workers (the driver
// waits for them and checks their figures first), naming the update, though update_n never
// returned its figures.
TEST(OffPolicyDriver, ChecksUpdatesStillRunningBeforeWeightsLeave) {
  StepScaleFarm farm;
  // Groups of kUpdatesPerGroup (8): the second group's updates 9-13 come back, 14-16 are held.
  auto algo = driver_with_updates_held(15, 4, farm);
  EXPECT_EQ(farm.published_, 1);
  algo->train(farm, true);  // updates 1-8, publish after 6-8 are checked
  EXPECT_EQ(algo->updates(), 8);
  EXPECT_EQ(farm.published_, 2);
  try {
    algo->train(farm, true);
    ADD_FAILURE() << "update 15's NaN critic loss reached a publish";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("diverged at update 15"), std::string::npos) << e.what();
  }
  EXPECT_EQ(farm.published_, 2);
}

// A divergence that a periodic checkpoint finds (the farm logs a failed checkpoint and goes on)
// stays found: the next train() and the next weights for the workers throw it again, though its
// figures have been read, and nothing is published.
TEST(OffPolicyDriver, ADivergenceACheckpointFoundStopsWhatFollows) {
  StepScaleFarm farm;
  // The first group's updates 1-5 come back, 6-8 (update 7 NaN) are held.
  auto algo = driver_with_updates_held(7, 100, farm);
  algo->train(farm, true);
  EXPECT_EQ(algo->updates(), 8);
  const auto dir = std::filesystem::temp_directory_path() / ("diverged_ckpt_" + std::to_string(::getpid()));
  EXPECT_THROW(algo->save(dir.string()), std::runtime_error);
  EXPECT_FALSE(std::filesystem::exists(dir));
  for (int k = 0; k < 2; ++k) {
    try {
      algo->train(farm, true);
      ADD_FAILURE() << "train() went on after update 7's NaN critic loss";
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find("diverged at update 7"), std::string::npos) << e.what();
    }
  }
  EXPECT_THROW(algo->hold_workers(farm), std::runtime_error);
  EXPECT_EQ(farm.published_, 1);
}

}  // namespace
}  // namespace farm
