#include "run_policy.h"

#include <google/protobuf/text_format.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

#include "config.h"
#include "ppo.h"
#include "registry.h"

namespace farm::tools {

namespace fs = std::filesystem;

namespace {

// A manifest is a config and counters: a few kB to a few hundred; anything far bigger is not one.
constexpr std::uintmax_t kMaxManifestBytes = 16u << 20;

config::CheckpointManifest read_manifest_file(const fs::path& file) {
  std::error_code ec;
  const auto size = fs::file_size(file, ec);
  if (ec) throw std::runtime_error("cannot read " + file.string() + ": " + ec.message());
  if (size > kMaxManifestBytes)
    throw std::runtime_error(file.string() + " is " + std::to_string(size) +
                             " bytes, more than a manifest's limit of " + std::to_string(kMaxManifestBytes));
  std::ifstream in(file);
  if (!in) throw std::runtime_error("cannot read " + file.string());
  std::stringstream ss;
  ss << in.rdbuf();
  config::CheckpointManifest m;
  if (!google::protobuf::TextFormat::ParseFromString(ss.str(), &m))
    throw std::runtime_error("cannot parse " + file.string() + " as a checkpoint manifest");
  if (m.config_text().empty()) throw std::runtime_error(file.string() + " holds no experiment config");
  return m;
}

}  // namespace

std::string run_policy_dir(const std::string& run, bool best) {
  if (!fs::is_directory(run)) throw std::runtime_error("run folder " + run + " does not exist");
  const fs::path dir = fs::path(run) / (best ? "best" : "checkpoint");
  if (fs::is_directory(dir)) return dir.string();
  std::string holds;
  for (const char* sub : {"checkpoint", "best"})
    if (fs::is_directory(fs::path(run) / sub)) holds += std::string(holds.empty() ? "" : " and ") + sub + "/";
  throw std::runtime_error("no policy in " + run + ": it has no " + (best ? "best/" : "checkpoint/") +
                           (holds.empty() ? " (it holds no checkpoint/ or best/ at all: is it a run folder?)"
                                          : " (it holds " + holds + ")"));
}

namespace {

// The policy of the config's algorithm: its networks read from `dir` (a checkpoint folder, in the
// algorithm's sub-folder) or, with an empty `dir`, as its learner initializes them.
PolicyParams export_policy(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec, const std::string& dir,
                           uint64_t version) {
  const AlgorithmRegistration& a = find_algorithm(cfg.algorithm());
  auto networks = [&](const std::string& sub) {
    const fs::path p = fs::path(dir) / sub;
    if (!fs::is_directory(p))
      throw std::runtime_error("no policy in " + dir + ": no " + sub + "/ (the " + cfg.algorithm() +
                               " networks the experiment names)");
    return p.string();
  };
  if (a.make_off_policy) {
    auto algo = a.make_off_policy(cfg, spec);
    if (!dir.empty()) algo->load(networks(algo->name()));
    return algo->export_policy(version);
  }
  if (cfg.algorithm() == "ppo") {
    Ppo ppo(cfg.ppo(), spec.obs_dim, spec.act_dim, cfg.seed());
    if (!dir.empty()) ppo.load(networks("ppo"));
    return ppo.export_policy(version);
  }
  throw std::runtime_error("cannot make a policy of algorithm '" + cfg.algorithm() + "'" +
                           (dir.empty() ? std::string() : " from " + dir));
}

}  // namespace

RunPolicy config_policy(const std::string& config_path, const std::string& dir) {
  if (!dir.empty() && !fs::is_directory(dir)) throw std::runtime_error("checkpoint folder " + dir + " does not exist");
  RunPolicy r;
  r.dir = dir;
  r.config = load_config_file(config_path);
  r.task = robots::make_task(r.config.task());
  r.policy = export_policy(r.config, r.task->spec(), dir, 0);
  return r;
}

RunPolicy load_run_policy(const std::string& dir) {
  if (!fs::is_directory(dir)) throw std::runtime_error("checkpoint folder " + dir + " does not exist");
  const fs::path manifest = fs::path(dir) / "manifest.txtpb";
  if (!fs::exists(manifest)) {
    std::string hint;
    if (fs::is_directory(fs::path(dir) / "checkpoint") || fs::is_directory(fs::path(dir) / "best"))
      hint = " (it is a run folder: pass its checkpoint/ or best/)";
    throw std::runtime_error("no policy in " + dir + ": no manifest.txtpb" + hint);
  }
  RunPolicy r;
  r.dir = dir;
  r.manifest = read_manifest_file(manifest);
  r.config = parse_config_text(r.manifest.config_text(), manifest.string());
  r.task = robots::make_task(r.config.task());
  r.policy = export_policy(r.config, r.task->spec(), dir, r.manifest.policy_version());
  return r;
}

}  // namespace farm::tools
