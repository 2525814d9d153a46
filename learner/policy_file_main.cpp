// farm-policy-file [--config EXPERIMENT.txtpb] DIR: writes the policy file (policy.bin,
// common/policy_file.h) of a folder of an algorithm's networks: a checkpoint or best folder from its
// manifest, for folders a learner wrote before it wrote policy files, or, with --config, a folder
// of networks without a manifest (its version is then the networks' update count). The programs
// that run a trained policy (farm-play, farm-export, farm-mobile-eval, farm-mclari-eval) read that
// file and link no LibTorch; this program has LibTorch.
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
#include "task_specs.h"

namespace fs = std::filesystem;

int main(int argc, char** argv) {
  farm::cli::App app("farm-policy-file");
  app.description(std::string("Writes CHECKPOINT_DIR/") + farm::kPolicyFileName +
                  ", the policy in the workers' layout, from the folder's manifest.txtpb (or --config) and its "
                  "algorithm's networks (RUN/checkpoint or RUN/best of any learner).");
  std::string dir, config_path;
  app.add_option("checkpoint_dir", dir, "a checkpoint or best folder")->required()->check(CLI::ExistingDirectory);
  app.add_option("--config", config_path,
                 "The experiment of a folder without a manifest (its networks only); the policy's version is "
                 "then their update count")
      ->check(CLI::ExistingFile);
  if (const int rc = farm::cli::parse(app, argc, argv); rc >= 0) return rc;
  try {
    farm::config::ExperimentConfig cfg;
    uint64_t version = 0;
    if (!config_path.empty()) {
      cfg = farm::robots::load_config_file(config_path);
    } else {
      const fs::path manifest_file = fs::path(dir) / "manifest.txtpb";
      std::ifstream in(manifest_file);
      if (!in)
        throw std::runtime_error("cannot read " + manifest_file.string() +
                                 " (for a folder without a manifest, name its experiment with --config)");
      std::stringstream text;
      text << in.rdbuf();
      farm::config::CheckpointManifest m;
      if (!google::protobuf::TextFormat::ParseFromString(text.str(), &m) || m.config_text().empty())
        throw std::runtime_error(manifest_file.string() + " is not a checkpoint manifest with its config_text");
      cfg = farm::robots::parse_config_text(m.config_text(), manifest_file.string() + " config_text");
      version = m.policy_version();
    }
    int64_t updates = 0;
    farm::PolicyParams p = farm::read_saved_policy(cfg, farm::robots::task_spec(cfg.task()), dir, version, &updates);
    if (!config_path.empty()) p.version = uint64_t(updates);
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
