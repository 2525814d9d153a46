// farm-policy-file CHECKPOINT_DIR: writes the policy file (policy.bin, common/policy_file.h) of a
// checkpoint or best folder from its manifest and the networks of its algorithm, for folders a
// learner wrote before it wrote policy files. The programs that run a trained policy (farm-export,
// farm-mobile-eval, ...) read that file and link no LibTorch; this program has LibTorch.
#include <google/protobuf/text_format.h>

#include <cstdio>
#include <exception>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <string>

#include "cli.h"
#include "config.h"
#include "farm_config.pb.h"
#include "policy_file.h"
#include "registry.h"
#include "task_spec.h"

namespace fs = std::filesystem;

int main(int argc, char** argv) {
  farm::cli::App app("farm-policy-file");
  app.description(std::string("Writes CHECKPOINT_DIR/") + farm::kPolicyFileName +
                  ", the policy in the workers' layout, from the folder's manifest.txtpb and its algorithm's "
                  "networks (RUN/checkpoint or RUN/best of any learner).");
  std::string dir;
  app.add_option("checkpoint_dir", dir, "a checkpoint or best folder")->required()->check(CLI::ExistingDirectory);
  if (const int rc = farm::cli::parse(app, argc, argv); rc >= 0) return rc;
  try {
    const fs::path manifest_file = fs::path(dir) / "manifest.txtpb";
    std::ifstream in(manifest_file);
    if (!in) throw std::runtime_error("cannot read " + manifest_file.string());
    std::stringstream text;
    text << in.rdbuf();
    farm::config::CheckpointManifest m;
    if (!google::protobuf::TextFormat::ParseFromString(text.str(), &m) || m.config_text().empty())
      throw std::runtime_error(manifest_file.string() + " is not a checkpoint manifest with its config_text");
    const farm::config::ExperimentConfig cfg =
        farm::parse_config_text(m.config_text(), manifest_file.string() + " config_text");
    int64_t updates = 0;
    const farm::PolicyParams p =
        farm::read_saved_policy(cfg, farm::robots::task_spec(cfg.task()), dir, m.policy_version(), &updates);
    const fs::path out = fs::path(dir) / farm::kPolicyFileName;
    farm::write_policy_file(out.string(), p);
    std::printf("farm-policy-file: %s: policy v%llu of %s, %s, %lld updates\n", out.c_str(),
                (unsigned long long)p.version, cfg.algorithm().c_str(), p.layout.describe().c_str(),
                (long long)updates);
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "farm-policy-file: %s\n", e.what());
    return 1;
  }
}
