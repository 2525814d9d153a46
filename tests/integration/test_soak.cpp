// Soak: three workers and a learner for 100 s on a machine with fewer cores than
// processes, so the learner is the bottleneck and the workers are held back. Every sequence number
// each worker sent must arrive exactly once, nothing may be lost, and memory must stay bounded.
#include <gtest/gtest.h>

#include <regex>
#include <string>

#include "process_util.h"

using namespace farm::testing;

namespace {

const char* kConfig = R"(experiment_id: "it_soak"
seed: 21
task { name: "pendulum" }
# A new policy every 200 updates (a few per second) while a worker fills its 4 batches of a
# version in tens of milliseconds: the workers wait on the learner whatever the machine's speed.
sac { hidden: 64 hidden: 64 actor_lr: 1e-3 critic_lr: 1e-3 alpha_lr: 1e-3 learning_starts: 1000
      publish_every_updates: 200 buffer_size: 100000 }
worker { envs_per_worker: 16 steps_per_batch: 25 max_batches_per_version: 4 }
eval { episodes: 5 every_seconds: 30 final_episodes: 10 }
stop { max_seconds: 100 }
checkpoint_every_seconds: 30
log_every_seconds: 5
)";

// Peak resident memory of a process in MiB (VmHWM), read while it still runs.
double peak_rss_mib(pid_t pid) {
  std::string status = slurp("/proc/" + std::to_string(pid) + "/status");
  std::smatch m;
  if (!std::regex_search(status, m, std::regex(R"(VmHWM:\s+(\d+) kB)"))) return -1;
  return std::stod(m[1]) / 1024.0;
}

TEST(Soak, ThreeWorkersNothingLostMemoryBounded) {
  ProcessSet set;
  const std::string d = set.dir(), domain = std::to_string(private_domain(97)), run = d + "/run";
  write_file(d + "/soak.txtpb", kConfig);
  Proc& learner =
      set.start({FARM_LEARNER_BIN, "--config", d + "/soak.txtpb", "--run-dir", run, "--domain", domain}, "learner");
  const std::vector<std::string> ids = {"soak-a", "soak-b", "soak-c"};
  for (auto& id : ids) set.start({FARM_WORKER_BIN, "--domain", domain, "--id", id}, id);

  // Sample peak memory near the end, while everything still runs.
  ASSERT_TRUE(wait_until(
      [&] {
        const auto p = events(run, "progress");
        return !p.empty() && p.back().value("elapsed_s", 0.0) >= 90;
      },
      200))
      << set.log("learner");
  const double learner_mib = peak_rss_mib(learner.pid);
  // The replay buffer was full by then: its memory is all taken, and the bound below covers it.
  EXPECT_GE(events(run, "progress").back().value("buffer_fill", 0.0), 1.0) << slurp(run + "/events.jsonl");
  std::vector<double> worker_mib;
  for (size_t i = 1; i <= ids.size(); ++i) worker_mib.push_back(peak_rss_mib(set.procs()[i].pid));

  ASSERT_EQ(wait_for(learner, 120), 0) << set.log("learner");
  const nlohmann::json summary = summary_event(run);
  EXPECT_TRUE(no_batch_lost_or_refused(summary)) << summary << slurp(run + "/events.jsonl");
  for (size_t i = 0; i < ids.size(); ++i) {
    EXPECT_EQ(wait_for(set.procs()[i + 1], 60), 0) << set.log(ids[i]);
    const long long sent = set.batches_sent(ids[i]);
    ASSERT_GE(sent, 0) << set.log(ids[i]);
    EXPECT_EQ(closed_whole_stream(summary, ids[i]), sent) << ids[i] << "\n" << summary;
    EXPECT_GT(sent, 500) << ids[i];
  }
  // The workers were held back rather than piling data up, and the learner's progress said so.
  int throttled = 0;
  for (const auto& e : events(run, "progress")) throttled = std::max(throttled, e.value("workers_throttled", 0));
  EXPECT_GT(throttled, 0) << slurp(run + "/events.jsonl");
  // Bounds (see docs/record/reliability.md): replay buffer 100,000 x (3+1+3+2) floats is 3.4 MiB, full; the DDS
  // queues hold at most 256 batches of 16x25 steps at the learner and 64 per worker; LibTorch and
  // Fast DDS themselves take a few hundred MiB.
  std::printf("peak RSS: learner %.0f MiB, workers %.0f / %.0f / %.0f MiB\n", learner_mib, worker_mib[0], worker_mib[1],
              worker_mib[2]);
  EXPECT_GT(learner_mib, 0);
  EXPECT_LT(learner_mib, 1024);
  for (double w : worker_mib) EXPECT_LT(w, 256);
  set.cleanup(::testing::Test::HasFailure());
}

}  // namespace
