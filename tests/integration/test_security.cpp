// DDS Security end to end: a CA and per-participant certificates from deploy/make-pki.sh, a real
// learner and worker training with security on, and three outsiders trying to publish batches and
// read the spec and weights: one without security, one with a certificate from another CA, and one
// with a valid worker certificate as the control that shows the outsider program does work.
#include <gtest/gtest.h>

#include <regex>
#include <string>

#include "process_util.h"

using namespace farm::testing;

namespace {

const char* kConfig = R"(experiment_id: "it_secure"
seed: 5
task { name: "pendulum" }
sac { hidden: 64 hidden: 64 actor_lr: 1e-3 critic_lr: 1e-3 alpha_lr: 1e-3 learning_starts: 1000 publish_every_updates: 25 }
worker { envs_per_worker: 8 steps_per_batch: 25 max_batches_per_version: 2 }
eval { episodes: 5 every_seconds: 5 final_episodes: 10 }
stop { max_seconds: 40 }
log_every_seconds: 2
)";

TEST(Security, OnlyCertifiedParticipantsTrainOrSeeTheFarm) {
  ProcessSet set;
  const std::string d = set.dir(), domain = std::to_string(private_domain(77));
  const std::string pki = std::string(FARM_SOURCE_DIR) + "/deploy/make-pki.sh";
  ASSERT_EQ(std::system(("bash " + pki + " " + d + "/pki learner worker-a insider > " + d + "/pki.log 2>&1").c_str()),
            0)
      << slurp(d + "/pki.log");
  // Same participant name, certificate from a CA the farm does not trust.
  ASSERT_EQ(std::system(("bash " + pki + " " + d + "/rogue worker-a > " + d + "/rogue.log 2>&1").c_str()), 0)
      << slurp(d + "/rogue.log");
  write_file(d + "/secure.txtpb", kConfig);

  Proc& learner = set.start({FARM_LEARNER_BIN, "--config", d + "/secure.txtpb", "--run-dir", d + "/run", "--domain",
                             domain, "--security", d + "/pki/learner"},
                            "learner");
  Proc& worker =
      set.start({FARM_WORKER_BIN, "--domain", domain, "--id", "worker-a", "--security", d + "/pki/worker-a"}, "worker");
  // The outsiders try for 22 s. The certified insider, the control, sends for most of the
  // learner's 40 s: on 2 busy cores it once matched nothing within 15 s (a secure handshake can
  // need resends), and a control that has too little time fails the test for the wrong reason.
  auto outsider = [&](const std::string& id, const std::vector<std::string>& extra,
                      const char* seconds = "22") -> Proc& {
    std::vector<std::string> argv = {FARM_INTRUDER_BIN, "--domain", domain, "--experiment", "it_secure", "--id", id,
                                     "--seconds",       seconds};
    argv.insert(argv.end(), extra.begin(), extra.end());
    return set.start(argv, id);
  };
  Proc& plain = outsider("intruder-plain", {});
  Proc& rogue = outsider("intruder-rogue", {"--security", d + "/rogue/worker-a"});
  Proc& insider = outsider("insider", {"--security", d + "/pki/insider"}, "36");

  for (Proc* p : {&plain, &rogue, &insider}) {
    int rc = wait_for(*p, 60);
    EXPECT_TRUE(rc == 0 || rc == 3) << p->log << "\n" << slurp(p->log);
  }
  ASSERT_EQ(wait_for(learner, 120), 0) << set.log("learner");
  EXPECT_EQ(wait_for(worker, 60), 0) << set.log("worker");

  // The control got through both ways, so the outsider program can get through.
  std::smatch m;
  const std::string ins = set.log("insider");
  ASSERT_TRUE(std::regex_search(
      ins, m, std::regex(R"(batch readers matched (\d+), weights received (\d+), specs received (\d+))")))
      << ins;
  EXPECT_GE(std::stoi(m[1]), 1) << ins;
  EXPECT_GE(std::stoi(m[2]), 1) << ins;
  EXPECT_GE(std::stoi(m[3]), 1) << ins;

  // The outsiders got nothing: no learner matched them, no weights or spec reached them.
  for (const char* id : {"intruder-plain", "intruder-rogue"}) {
    const std::string out = set.log(id);
    if (out.find(": refused:") != std::string::npos) continue;  // could not even join: also fine
    ASSERT_TRUE(std::regex_search(
        out, m, std::regex(R"(batch readers matched (\d+), weights received (\d+), specs received (\d+))")))
        << out;
    EXPECT_EQ(m[1], "0") << id << ": " << out;
    EXPECT_EQ(m[2], "0") << id << ": " << out;
    EXPECT_EQ(m[3], "0") << id << ": " << out;
  }

  // The learner trained with the real worker and never heard of the outsiders.
  const std::string summary = slurp(d + "/run/summary.txt");
  EXPECT_NE(summary.find("worker-a session"), std::string::npos) << summary;
  EXPECT_NE(summary.find("insider session"), std::string::npos) << summary;
  EXPECT_EQ(summary.find("intruder"), std::string::npos) << summary;
  ASSERT_TRUE(
      std::regex_search(summary, m, std::regex(R"(batches\s+ok (\d+), lost (\d+), duplicate (\d+), invalid (\d+))")));
  EXPECT_GT(std::stoll(m[1]), 100);
  EXPECT_EQ(m[4], "0") << summary;
  set.cleanup(::testing::Test::HasFailure());
}

}  // namespace
