// The replay pacing (learner/replay_pacing.cpp, samples_per_insert.h, replay_schedule.h): the
// samples-per-insert limiter; each pass's decision from counts and clocks alone; sac.max_step_scale's
// rule, SAC keeping the configured step on the CPU, and the pacing growing and shrinking the step
// against the env steps a farm reports; and updates that are still running on a GPU when update()
// returns: their figures are checked before any weights leave the learner. Then PPO's resume: the
// steps not yet fitted and the round pacing's accounts.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <deque>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <unistd.h>

#include "config.h"
#include "meter.h"
#include "pacing.h"
#include "paths.h"  // remove_tree: std::filesystem::remove_all crashes the GPU build
#include "registry.h"
#include "replay_schedule.h"
#include "samples_per_insert.h"
#include "step_size.h"
#include "task_specs.h"

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
  void row(const StatsRecord&) override {}
  uint64_t env_steps_ = 0;
  int published_ = 0;
  mutable std::vector<std::string> lines_;
};

// SAC as it is, but with what it would do on a GPU, so that the pacing's side runs here: the step
// scale (SAC keeps the configured step on the CPU), and, with `held` > 0, update() returning before the
// figures of its last `held` updates are in (they come with the next call or finish(), as a CUDA
// graph's queued replays do). Update `nan_at` (counted from 1) has a critic loss of NaN.
class StepScaleOnAnyDevice final : public Algorithm {
 public:
  StepScaleOnAnyDevice(std::unique_ptr<Algorithm> sac, int most, int held = 0, int64_t nan_at = 0)
      : sac_(std::move(sac)), most_(most), held_(held), nan_at_(nan_at) {}
  std::string name() const override { return sac_->name(); }
  std::string describe() const override { return sac_->describe(); }
  void insert(const Batch& b) override { sac_->insert(b); }
  Holding holding() const override { return sac_->holding(); }
  int64_t ready() const override { return sac_->ready(); }
  std::vector<UpdateFigures> update(int n, uint64_t v) override {
    for (const UpdateFigures& f : sac_->update(n, v)) {
      in_flight_.push_back(f);
      if (++made_ == nan_at_) in_flight_.back().values[0].second = NAN;
    }
    std::vector<UpdateFigures> out;
    while (int(in_flight_.size()) > held_) {
      out.push_back(in_flight_.front());
      in_flight_.pop_front();
    }
    return out;
  }
  std::vector<UpdateFigures> finish() override {
    std::vector<UpdateFigures> out(in_flight_.begin(), in_flight_.end());
    in_flight_.clear();
    return out;
  }
  int64_t updates() const override { return sac_->updates(); }
  int max_step_scale() const override { return most_; }
  void set_step_scale(int s) override { sac_->set_step_scale(s); }
  PolicyParams policy(uint64_t v) const override { return sac_->policy(v); }
  void save_networks(const std::string& dir) const override { sac_->save_networks(dir); }
  void save(const std::string& dir) const override { sac_->save(dir); }
  void load_networks(const std::string& dir) override { sac_->load_networks(dir); }
  void to_manifest(config::CheckpointManifest& m) const override { sac_->to_manifest(m); }
  std::string from_manifest(const config::CheckpointManifest& m) override { return sac_->from_manifest(m); }

 private:
  std::unique_ptr<Algorithm> sac_;
  int most_, held_;
  int64_t nan_at_, made_ = 0;
  std::deque<UpdateFigures> in_flight_;
};

config::ExperimentConfig step_scale_config() {
  return robots::parse_config_text(
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

// On the CPU a batch four times as large costs nearly four times the time, so SAC keeps the
// configured step there whatever sac.max_step_scale says, and its start line says so.
TEST(SacStepScale, TheCpuKeepsTheConfiguredStep) {
  auto cfg = step_scale_config();
  cfg.mutable_sac()->set_device("cpu");
  const auto sac = make_algorithm(cfg, step_scale_spec());
  EXPECT_EQ(sac->max_step_scale(), 1);
  EXPECT_NE(sac->describe().find("the configured step (sac.max_step_scale is for a GPU learner)"), std::string::npos)
      << sac->describe();
  // The pacing never asks it here; if asked, the minibatch follows: 32 rows are two of 16, no x4.
  sac->insert(OneStep(32).batch);
  EXPECT_GT(sac->ready(), 0);
  sac->set_step_scale(4);
  EXPECT_EQ(sac->ready(), 0);
}

// A schedule of 160 updates to 0.2: 1 until the first of 16 steps (10 updates), 0.6 halfway, 0.2 from
// update 160 on; no schedule, 1 throughout.
TEST(LrDecay, FallsInSixteenStepsThenStays) {
  EXPECT_EQ(lr_decay_factor(0, 1.0, 0), 1.0);
  EXPECT_EQ(lr_decay_factor(0, 0.2, 1000000), 1.0);
  EXPECT_DOUBLE_EQ(lr_decay_factor(160, 0.2, 0), 1.0);
  EXPECT_DOUBLE_EQ(lr_decay_factor(160, 0.2, 9), 1.0);
  EXPECT_DOUBLE_EQ(lr_decay_factor(160, 0.2, 10), 1.0 - 0.8 / 16);
  EXPECT_DOUBLE_EQ(lr_decay_factor(160, 0.2, 80), 0.6);
  EXPECT_DOUBLE_EQ(lr_decay_factor(160, 0.2, 159), 1.0 - 0.8 * 15 / 16);
  EXPECT_DOUBLE_EQ(lr_decay_factor(160, 0.2, 160), 0.2);
  EXPECT_DOUBLE_EQ(lr_decay_factor(160, 0.2, 1000000), 0.2);
  EXPECT_EQ(lr_decay_phrase(0, 0.2), "");
  EXPECT_EQ(lr_decay_phrase(160, 1.0), "");
  EXPECT_EQ(lr_decay_phrase(160, 0.2), ", learning rates to x0.2 over 160 updates");
}

// The schedule (sac.lr_decay_updates, dqn.lr_decay_updates) reaches the updates: with 32 updates to
// x0.25 in 16 steps the rates first fall at update 3 (after 2 made), so two runs from one seed, one
// with the schedule, agree after 2 updates and not after 3. The start line says so.
TEST(LrDecay, EachOffPolicyAlgorithmTakesTheScheduledRates) {
  for (const std::string algorithm : {"sac", "dqn"}) {
    const std::string base = "experiment_id: \"lr\" algorithm: \"" + algorithm + "\"\n" + algorithm +
                             " { hidden: [8, 8] batch_size: 16 learning_starts: 0";
    const auto plain = robots::parse_config_text(base + " }\n", "lr.txtpb");
    const auto decay = robots::parse_config_text(base + " lr_decay_updates: 32 lr_decay_to: 0.25 }\n", "lr.txtpb");
    auto spec = step_scale_spec();
    if (algorithm == "dqn") spec.num_actions = 3;  // OneStep's actions (0.1) are index 0
    auto run = [&spec](const config::ExperimentConfig& cfg, int updates) {
      const auto a = make_algorithm(cfg, spec);  // seeds LibTorch: runs one after the other
      a->insert(OneStep(64).batch);
      for (int k = 0; k < updates; ++k) a->update(1, 1);
      return a->policy(1).params;
    };
    EXPECT_EQ(run(plain, 2), run(decay, 2)) << algorithm;
    EXPECT_NE(run(plain, 3), run(decay, 3)) << algorithm;
    const std::string start = make_algorithm(decay, spec)->describe();
    EXPECT_NE(start.find(", learning rates to x0.25 over 32 updates"), std::string::npos) << start;
  }
}

// sac.n_step reaches the start line; 1, the seed's, says nothing.
TEST(SacStepScale, MultiStepReturnsAreSaid) {
  auto cfg = step_scale_config();
  EXPECT_EQ(make_algorithm(cfg, step_scale_spec())->describe().find("-step returns"), std::string::npos);
  cfg.mutable_sac()->set_n_step(3);
  const auto sac = make_algorithm(cfg, step_scale_spec());
  EXPECT_NE(sac->describe().find(", 3-step returns"), std::string::npos) << sac->describe();
}

// The samples-per-insert limiter: nothing before min_rows; then updates within per_step x env steps
// (+1), and none past max_updates.
TEST(SamplesPerInsert, HoldsUpdatesToTheDataAndTheLimit) {
  const SamplesPerInsert lim(100, 0.5, 1000);
  EXPECT_EQ(lim.allowed(0, 99, 1000000, 8), 0) << "below min_rows";
  EXPECT_EQ(lim.allowed(0, 100, 0, 8), 1) << "the first update needs rows only";
  EXPECT_EQ(lim.allowed(0, 100, 10, 8), 6) << "updates 0..5 are below 0.5 x 10 + 1";
  EXPECT_EQ(lim.allowed(6, 100, 10, 8), 0);
  EXPECT_EQ(lim.allowed(0, 100, 1000000, 8), 8) << "at most `most`";
  EXPECT_EQ(lim.allowed(996, 100, 1000000, 8), 4) << "none past max_updates";
  EXPECT_EQ(SamplesPerInsert(0, 2.0, 0).allowed(5000, 1, 10000, 3), 3) << "no max_updates";
}

// A pass's decision from counts and clocks alone: updates as the limiter allows within a group, a
// version after every publish_every updates or whenever the pass is starved with something new, an
// evaluation on its timer once an update has run, and a short wait only when nothing came.
TEST(ReplaySchedule, DecidesUpdatesPublishingAndEvaluationsFromCountsAndClocks) {
  const ReplaySchedule sched{SamplesPerInsert(100, 0.5, 0), 8, 25, 5.0};
  ReplaySnapshot s;
  s.rows = 99;
  s.ready = 8;
  s.env_steps = 1000;
  ReplayDecision d = sched.decide(s);
  EXPECT_EQ(d.updates, 0) << "below learning_starts";
  EXPECT_FALSE(d.publish) << "nothing new since the last version";
  EXPECT_FALSE(d.evaluate);
  EXPECT_DOUBLE_EQ(d.wait, 0.01) << "no update and no data: the runner may wait";
  s.got_data = true;
  s.batches_since_publish = 3;
  d = sched.decide(s);
  EXPECT_TRUE(d.publish) << "starved with batches since the last version: a new one lets the workers go";
  EXPECT_DOUBLE_EQ(d.wait, 0.0);

  s.rows = 1000;
  s.batches_since_publish = 0;
  d = sched.decide(s);
  EXPECT_EQ(d.updates, 8) << "a group";
  EXPECT_FALSE(d.publish) << "8 of 25 updates";
  s.ready = 3;
  EXPECT_EQ(sched.decide(s).updates, 3) << "what the algorithm has the data for";
  s.ready = 8;
  s.updates = 495;  // 0.5 x 1000 + 1 allows updates 0..500
  EXPECT_EQ(sched.decide(s).updates, 6) << "what the data received allows";
  s.updates = 100;
  s.updates_since_publish = 20;
  d = sched.decide(s);
  EXPECT_TRUE(d.publish) << "20 + 8 updates since the last version";

  s.since_eval = 4.9;
  EXPECT_FALSE(sched.decide(s).evaluate);
  s.since_eval = 5.0;
  EXPECT_TRUE(sched.decide(s).evaluate);
  s.updates = 0;
  s.rows = 10;
  EXPECT_FALSE(sched.decide(s).evaluate) << "no update has run yet";
}

// The driver's side of sac.max_step_scale: while the env steps received allow far more updates
// than it makes, the step grows to the configured most; once no data comes, it falls back.
TEST(SacStepScale, DriverScalesWhileDataOutrunUpdatesAndBack) {
  const auto cfg = step_scale_config();
  const auto spec = step_scale_spec();
  auto algo = make_replay_pacing(std::make_unique<StepScaleOnAnyDevice>(make_algorithm(cfg, spec), 4), cfg, spec);
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

std::vector<std::string> split(const std::string& line, char sep) {
  std::vector<std::string> out;
  std::stringstream in(line);
  std::string item;
  while (std::getline(in, item, sep)) out.push_back(item);
  return out;
}

// sac.samples_per_insert: the same ratio at batches of 16 and 32 lets the updates draw the same
// samples per env step (twice the updates at half the batch), the limit holds, and the learner's
// CSV row says the ratio the updates reached. With sac.max_step_scale too, the pacing refuses.
TEST(ReplayPacing, SamplesPerInsertMeansTheSameAtAnyBatch) {
  struct Csv final : Farm {
    void publish(const PolicyParams&, uint32_t) override {}
    std::vector<LiveWorker> live_workers() const override { return {}; }
    double first_worker_heard() const override { return 0; }
    FarmFigures figures() const override { return {}; }
    uint64_t env_steps() const override { return 400; }
    double elapsed() const override { return 0; }
    bool ask_evaluation(const PolicyParams&, const EvalAsk&) override { return true; }
    void record_evaluation(const EvalReport&, uint64_t, int64_t, double) override {}
    void log(const std::string&) const override {}
    void row(const StatsRecord& r) override { last = r.csv_row(); }
    std::string last;
  };
  const auto spec = step_scale_spec();
  for (const int batch : {16, 32}) {
    SCOPED_TRACE("batch " + std::to_string(batch));
    auto cfg = step_scale_config();
    cfg.mutable_sac()->set_max_step_scale(1);
    cfg.mutable_sac()->set_batch_size(batch);
    cfg.mutable_sac()->set_samples_per_insert(32);  // 32 samples a step: 2 updates of 16, 1 of 32
    auto pacing = make_replay_pacing(make_algorithm(cfg, spec), cfg, spec);
    Csv farm;
    pacing->start(farm);
    ASSERT_TRUE(pacing->take(OneStep(256).batch));
    for (int k = 0; k < 400; ++k) pacing->train(farm, true);
    // The limiter: updates made < per_step x env steps + 1, per_step = 32 / batch.
    EXPECT_EQ(pacing->updates(), 32 * 400 / batch + 1);
    FarmFigures f;
    f.env_steps = 400;
    pacing->progress(farm, f, 1.0);
    const auto header = split(pacing->csv_header(), ','), row = split(farm.last, ',');
    ASSERT_EQ(header.size(), row.size()) << farm.last;
    const auto at = std::find(header.begin(), header.end(), "samples_per_insert") - header.begin();
    ASSERT_LT(size_t(at), header.size()) << pacing->csv_header();
    EXPECT_NEAR(std::stod(row[at]), double(pacing->updates()) * batch / 400, 1e-3) << farm.last;
    // The columns readers know keep their names and order; those added since follow them.
    EXPECT_EQ(pacing->csv_header().rfind(
                  "elapsed_s,env_steps,env_steps_per_s,updates,updates_per_s,update_to_data,samples_per_insert,"
                  "buffer_fill,policy_version,policy_lag,critic_loss,actor_loss,alpha,mean_return,eval_return,"
                  "batches_ok,batches_lost,batches_duplicate,batches_invalid,workers,",
                  0),
              0u)
        << pacing->csv_header();
  }
  auto both = step_scale_config();  // max_step_scale 4
  both.mutable_sac()->set_samples_per_insert(32);
  EXPECT_THROW(make_replay_pacing(make_algorithm(both, spec), both, spec), std::invalid_argument);
}

// The replay driver over SAC whose groups return with their last 3 updates' figures still out (as
// on a GPU), update `nan_at` NaN, publishing every `publish_every` updates; started, with data for
// a million updates and one batch taken.
std::unique_ptr<Pacing> driver_with_updates_held(int64_t nan_at, int publish_every, StepScaleFarm& farm) {
  auto cfg = step_scale_config();
  cfg.mutable_sac()->set_max_step_scale(1);
  cfg.mutable_sac()->set_publish_every_updates(publish_every);
  const auto spec = step_scale_spec();
  auto algo =
      make_replay_pacing(std::make_unique<StepScaleOnAnyDevice>(make_algorithm(cfg, spec), 1, 3, nan_at), cfg, spec);
  farm.env_steps_ = 1000000;
  algo->start(farm);
  EXPECT_TRUE(algo->take(OneStep(128).batch));
  return algo;
}

// A group of updates may return while its last ones still run on the GPU. A diverged update among
// those must stop the run before the next publish sends its weights to the workers (the driver
// waits for them and checks their figures first), naming the update, though update_n never
// returned its figures.
TEST(ReplayPacing, ChecksUpdatesStillRunningBeforeWeightsLeave) {
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
TEST(ReplayPacing, ADivergenceACheckpointFoundStopsWhatFollows) {
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

namespace farm {
namespace {

// A batch of PPO's shapes (step_scale_spec's) made by `version`: `rows` envs, one step each.
struct PpoStep : OneStep {
  PpoStep(int rows, uint64_t version) : OneStep(rows), log_probs(rows, -1.f) {
    batch.policy_version = version;
    batch.log_probs = log_probs.data();
    batch.episodes = &episodes;
  }
  std::vector<float> log_probs;
  std::vector<FinishedEpisode> episodes;
};

// What the round pacing sees of a farm: the live workers the test sets (by their heartbeats), the
// quota of each publish.
class RoundFarm final : public Farm {
 public:
  void publish(const PolicyParams& p, uint32_t quota) override { published.push_back({p.version, quota}); }
  std::vector<LiveWorker> live_workers() const override { return live; }
  double first_worker_heard() const override { return heard; }
  FarmFigures figures() const override { return {}; }
  uint64_t env_steps() const override { return 0; }
  double elapsed() const override { return 0; }
  bool ask_evaluation(const PolicyParams&, const EvalAsk& a) override {
    asked.push_back(a);
    return true;
  }
  void record_evaluation(const EvalReport&, uint64_t, int64_t, double) override {}
  void log(const std::string&) const override {}
  void row(const StatsRecord& r) override { rows.push_back(r.csv_row()); }
  std::vector<EvalAsk> asked;
  std::vector<LiveWorker> live;
  std::vector<std::string> rows;  // learner.csv's
  double heard = 0;
  std::vector<std::pair<uint64_t, uint32_t>> published;  // (version, quota)
};

// A PPO round pacing of 256 steps a fit, workers of 8 environments and 4 steps a batch (one batch:
// 32 steps), with `ppo_more` added to its ppo section; started on `farm`, whose workers are `live`
// and were first heard 2 s ago, so that its first version is published.
std::unique_ptr<Pacing> started_round_pacing(RoundFarm& farm, std::vector<Farm::LiveWorker> live,
                                             const std::string& ppo_more = "") {
  const auto cfg = robots::parse_config_text(
      "experiment_id: \"rounds\" algorithm: \"ppo\" eval { every_seconds: 100000 }\n"
      "worker { envs_per_worker: 8 steps_per_batch: 4 }\n"
      "ppo { hidden: [8, 8] steps_per_fit: 256 mini_batch_size: 64 epochs: 1 " +
          ppo_more + " }\n",
      "rounds.txtpb");
  auto pacing = make_pacing(cfg, step_scale_spec());
  farm.live = std::move(live);
  farm.heard = now_seconds() - 2;
  pacing->start(farm);
  pacing->train(farm, false);
  return pacing;
}

// A fit's row waits for the evaluation asked at that fit and is written with its report in the
// evaluation columns; learner.csv's columns keep the names and order its readers know.
TEST(RoundPacing, AFitsRowIsWrittenWithTheEvaluationAskedAtIt) {
  RoundFarm farm;
  const auto pacing = started_round_pacing(farm, {{"w1", "running", 0, 8}}, "eval_every_fits: 1");
  const uint64_t v = farm.published.back().first;
  for (int sent = 0; sent < 100 && farm.asked.empty(); ++sent) {
    PpoStep b(32, v);
    b.batch.worker_id = "w1";
    ASSERT_TRUE(pacing->take(b.batch));
    pacing->train(farm, true);
  }
  ASSERT_GT(pacing->updates(), 0);
  ASSERT_EQ(farm.asked.size(), 1u);  // at the first fit
  EXPECT_TRUE(farm.rows.empty()) << farm.rows.front();
  EvalReport r;
  r.episodes = 4;
  r.mean = -100.5;
  r.min = -120;
  r.max = -81.25;
  r.mean_length = 200;
  pacing->evaluated(farm, farm.asked[0], r);
  ASSERT_EQ(farm.rows.size(), 1u);
  const std::string header = pacing->csv_header();
  EXPECT_EQ(header.rfind("elapsed_s,fit,policy_version,env_steps,steps_used,steps_carried,stale_dropped,lag_mean,"
                         "lag_max,fit_seconds,kl,learning_rate,clip_fraction,value_loss,policy_loss,entropy,"
                         "mean_return,eval_return,eval_min,eval_max,eval_length,batches_ok,batches_lost,"
                         "batches_duplicate,batches_invalid,batches_stale,workers,episodes",
                         0),
            0u)
      << header;
  const auto names = split(header, ','), cells = split(farm.rows[0], ',');
  ASSERT_EQ(names.size(), cells.size()) << farm.rows[0];
  const auto cell = [&](const std::string& n) {
    return cells[std::find(names.begin(), names.end(), n) - names.begin()];
  };
  EXPECT_EQ(cell("fit"), "1");
  EXPECT_EQ(cell("policy_version"), std::to_string(v));
  EXPECT_EQ(cell("steps_used"), "256");
  EXPECT_EQ(cell("eval_return"), "-100.500");
  EXPECT_EQ(cell("eval_min"), "-120.000");
  EXPECT_EQ(cell("eval_max"), "-81.250");
  EXPECT_EQ(cell("eval_length"), "200.0");
}

// A participant that beats as a worker of 4,096 environments and never sends a batch (a stuck
// worker, or anyone without security) is not waited for: the quota is topped up once the worker
// that does send delivered, the fit comes, and the next version's quota is sized by the workers
// that send. Before, the fit waited for its batches for as long as it beat.
TEST(RoundPacing, AWorkerThatBeatsButNeverSendsHoldsNoFitBack) {
  RoundFarm farm;
  const auto pacing = started_round_pacing(farm, {{"w1", "running", 0, 8}, {"ghost", "running", 0, 4096}});
  ASSERT_EQ(farm.published.size(), 1u);
  const uint64_t v = farm.published.back().first;
  uint32_t quota = farm.published.back().second;
  uint32_t sent = 0;
  // w1 sends what its quota allows, one 32-step batch at a time, while the ghost beats on.
  for (int pass = 0; pass < 100 && pacing->updates() == 0; ++pass) {
    quota = farm.published.back().second;
    while (sent < quota && pacing->updates() == 0) {
      PpoStep b(32, v);
      b.batch.worker_id = "w1";
      ASSERT_TRUE(pacing->take(b.batch));
      ++sent;
      pacing->train(farm, true);
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(60));
    pacing->train(farm, false);
  }
  EXPECT_GT(pacing->updates(), 0) << "w1 sent " << sent << " batches, the last quota " << quota;
  // The next version's quota: one fit's 256 steps from w1's 32 a batch.
  ASSERT_GE(farm.published.size(), 2u);
  EXPECT_GT(farm.published.back().first, v);
  EXPECT_EQ(farm.published.back().second, 8u);
}

// A worker that sent, then stops sending on a version while its heartbeats go on (its collect loop
// hangs; the beat thread re-sends its last status) is not waited for past
// ppo.stalled_worker_seconds: the quota is topped up for the worker that still sends and the next
// fit comes from its batches. Before, every top-up waited for the hung worker's quota.
TEST(RoundPacing, AWorkerThatStopsSendingIsNotWaitedForPastTheStallTime) {
  RoundFarm farm;
  const auto pacing =
      started_round_pacing(farm, {{"w1", "running", 0, 8}, {"w2", "running", 0, 8}}, "stalled_worker_seconds: 0.5");
  ASSERT_EQ(farm.published.size(), 1u);
  const auto send = [&](const std::string& id, uint64_t version) {
    PpoStep b(32, version);
    b.batch.worker_id = id;
    EXPECT_TRUE(pacing->take(b.batch));
    pacing->train(farm, true);
  };
  // Version 1: both deliver a quota of 4 (two workers of 32 steps a batch for 256), and it fits.
  const uint64_t v1 = farm.published.back().first;
  ASSERT_EQ(farm.published.back().second, 4u);
  for (int k = 0; k < 4; ++k) send("w1", v1), send("w2", v1);
  const int64_t first_fit = pacing->updates();
  ASSERT_GT(first_fit, 0);
  ASSERT_EQ(farm.published.size(), 2u);
  const uint64_t v2 = farm.published.back().first;
  // Version 2: only w1 sends; w2 beats on, owing its 4.
  uint32_t sent = 0;
  for (int pass = 0; pass < 100 && pacing->updates() == first_fit; ++pass) {
    while (sent < farm.published.back().second && pacing->updates() == first_fit) {
      send("w1", v2);
      ++sent;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(60));
    pacing->train(farm, false);
  }
  EXPECT_GT(pacing->updates(), first_fit)
      << "w1 sent " << sent << " batches on v2, the last quota " << farm.published.back().second;
  EXPECT_EQ(sent, 8u);
}

config::ExperimentConfig resume_config() {
  return robots::parse_config_text(
      "experiment_id: \"resume\" algorithm: \"ppo\"\n"
      "ppo { hidden: [8, 8] steps_per_fit: 64 mini_batch_size: 16 epochs: 1 }\n",
      "resume.txtpb");
}

// A PPO checkpoint holds the steps accepted and not yet fitted: the resumed algorithm holds them
// toward its next fit, relabelled as made by the version it publishes their networks as, so a fit
// takes them with the steps that arrive after the resume. Without them it held nothing and
// waited for a whole fit's steps anew.
TEST(PpoResume, StepsNotYetFittedSurviveAResume) {
  const auto cfg = resume_config();
  const auto dir = std::filesystem::temp_directory_path() / ("ppo_resume_" + std::to_string(::getpid()));
  config::CheckpointManifest m;
  {
    const auto ppo = make_algorithm(cfg, step_scale_spec());
    PpoStep half(32, 7);
    ppo->insert(half.batch);
    EXPECT_EQ(ppo->holding().rows, 32);
    EXPECT_EQ(ppo->ready(), 0);
    ppo->save(dir.string());
    m.set_policy_version(7);
    ppo->to_manifest(m);
  }
  const uint64_t resumed = 7 + 1 + Pacing::kResumeVersionSkip;
  m.set_resumed_version(resumed);
  const auto again = make_algorithm(cfg, step_scale_spec());
  again->load(dir.string());
  again->from_manifest(m);
  EXPECT_EQ(again->holding().rows, 32);
  EXPECT_EQ(again->ready(), 0);
  PpoStep rest(32, resumed);
  again->insert(rest.batch);
  ASSERT_GT(again->ready(), 0);
  const auto figures = again->update(1, resumed);
  ASSERT_EQ(figures.size(), 1u);
  EXPECT_EQ(figures[0].get("steps used"), 64.0);
  EXPECT_EQ(figures[0].steps_by_version, (std::map<uint64_t, int64_t>{{resumed, 64}}));
  EXPECT_EQ(again->holding().rows, 0);
  farm::remove_tree(dir);
}

// The round pacing's accounts (steps counted stale, fitted, by lag) go into a checkpoint's
// manifest and come back on --resume, so the summary of a resumed run covers the whole run.
TEST(PpoResume, TheRoundPacingsAccountsSurviveAResume) {
  const auto cfg = resume_config();
  const auto first = make_pacing(cfg, step_scale_spec());
  config::CheckpointManifest m;
  first->to_manifest(m);
  m.set_policy_version(first->version());
  const auto resumed = make_pacing(cfg, step_scale_spec());
  resumed->resumed(m, 0);
  ASSERT_GT(resumed->version(), 0u);
  PpoStep old(16, 0);  // made before the resume by a version far behind the resumed one
  EXPECT_FALSE(resumed->take(old.batch));
  config::CheckpointManifest m2;
  resumed->to_manifest(m2);
  EXPECT_EQ(m2.stale_batches(), 1u);
  EXPECT_EQ(m2.stale_steps(), 16u);
  m2.set_policy_version(resumed->version());
  const auto third = make_pacing(cfg, step_scale_spec());
  third->resumed(m2, 0);
  config::CheckpointManifest m3;
  third->to_manifest(m3);
  EXPECT_EQ(m3.stale_batches(), 1u);
  EXPECT_EQ(m3.stale_steps(), 16u);
}

}  // namespace
}  // namespace farm
