// The loader of a run's policy (run_policy.h): the checkpoint manifest, bounded and parsed with the
// parser's first complaint, the task it names and the networks of its algorithm, on the CPU.
#include "run_policy.h"

#include <google/protobuf/io/tokenizer.h>
#include <google/protobuf/text_format.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

#include "config.h"
#include "registry.h"

namespace farm::tools {

namespace fs = std::filesystem;

namespace {

// A manifest is a config and counters: a few kB to a few hundred; anything far bigger is not one.
constexpr std::uintmax_t kMaxManifestBytes = 16u << 20;

std::string read_manifest_text(const fs::path& file) {
  std::error_code ec;
  const std::uintmax_t size = fs::file_size(file, ec);
  if (ec) throw std::runtime_error("cannot read " + file.string() + ": " + ec.message());
  if (size > kMaxManifestBytes)
    throw std::runtime_error(file.string() + " is " + std::to_string(size) +
                             " bytes, more than a manifest's limit of " + std::to_string(kMaxManifestBytes));
  std::ifstream in(file);
  if (!in) throw std::runtime_error("cannot read " + file.string());
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

config::CheckpointManifest read_manifest_file(const fs::path& file) {
  // The parser's first complaint, with its line and column, goes into the error (not to the log).
  struct FirstError : google::protobuf::io::ErrorCollector {
    std::string text;
    void AddError(int line, int column, const std::string& message) override {
      if (text.empty()) text = std::to_string(line + 1) + ":" + std::to_string(column + 1) + ": " + message;
    }
  } first_error;
  google::protobuf::TextFormat::Parser parser;
  parser.RecordErrorsTo(&first_error);
  config::CheckpointManifest m;
  if (!parser.ParseFromString(read_manifest_text(file), &m))
    throw std::runtime_error(file.string() + ":" + first_error.text + " (not a checkpoint manifest)");
  if (!m.has_config_text() || m.config_text().empty())
    throw std::runtime_error(file.string() + ": no config_text, so the task and the algorithm are unknown");
  return m;
}

// The policy of the config's algorithm: its networks read from `dir` (a checkpoint folder, in the
// algorithm's sub-folder) or, with an empty `dir`, as its learner initializes them, and their
// update count. The networks load on the CPU whatever device they trained on.
PolicyParams export_policy(config::ExperimentConfig cfg, const robots::TaskSpec& spec, const std::string& dir,
                           uint64_t version, int64_t* updates) {
  const std::string algorithm = cfg.algorithm();
  const AlgorithmRegistration& a = find_algorithm(algorithm);  // unknown: names the known ones
  if (!dir.empty()) {
    const fs::path file = fs::path(dir) / algorithm / (algorithm + ".pt");
    if (!fs::exists(file))
      throw std::runtime_error(file.string() + " does not exist (the networks of algorithm \"" + algorithm +
                               "\", which the experiment runs)");
  }
  cfg.mutable_sac()->set_device("cpu");
  cfg.mutable_ppo()->set_device("cpu");
  const std::string sub = dir.empty() ? std::string() : (fs::path(dir) / algorithm).string();
  if (a.make_off_policy) {
    auto algo = a.make_off_policy(cfg, spec);
    if (!dir.empty()) algo->load(sub);
    *updates = algo->updates();
    return algo->export_policy(version);
  }
  // An algorithm with its own driver reads its networks itself (its registration's read_policy).
  if (a.read_policy) return a.read_policy(cfg, spec, sub, version, updates);
  throw std::runtime_error("cannot make a policy of algorithm \"" + algorithm + "\"" +
                           (dir.empty() ? std::string() : " from " + dir) +
                           ": its registration (learner/algorithms/registry.cpp) has no read_policy");
}

// The config's task, built without writing any file its config names.
RunPolicy with_task(config::ExperimentConfig cfg) {
  clear_output_paths(&cfg);
  RunPolicy r;
  r.config = std::move(cfg);
  r.task = robots::make_task(r.config.task());
  return r;
}

}  // namespace

std::string run_policy_dir(const std::string& run, bool best) {
  const fs::path root(run);
  if (!fs::is_directory(root)) throw std::runtime_error("run folder " + run + " does not exist");
  const fs::path dir = root / (best ? "best" : "checkpoint");
  const fs::path manifest = dir / "manifest.txtpb";
  if (fs::exists(manifest)) return dir.string();
  std::string hint;
  if (best && fs::exists(root / "checkpoint" / "manifest.txtpb"))
    hint = " (it has a checkpoint: leave out --best)";
  else if (!best && fs::exists(root / "checkpoint.old" / "manifest.txtpb"))
    hint = " (a learner stopped while saving left " + (root / "checkpoint.old").string() + ")";
  else if (!fs::is_directory(root / "checkpoint") && !fs::is_directory(root / "best"))
    hint = " (it holds no checkpoint/ or best/ at all: is it a run folder?)";
  throw std::runtime_error("run folder " + run + " holds no policy: " + manifest.string() +
                           " does not exist; a learner writes RUN/checkpoint and RUN/best" + hint);
}

RunPolicy config_policy(const std::string& config_path, const std::string& dir) {
  if (!dir.empty() && !fs::is_directory(dir)) throw std::runtime_error("checkpoint folder " + dir + " does not exist");
  RunPolicy r = with_task(load_config_file(config_path));
  r.dir = dir;
  r.policy = export_policy(r.config, r.task->spec(), dir, 0, &r.updates);
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
  const config::CheckpointManifest m = read_manifest_file(manifest);
  RunPolicy r = with_task(parse_config_text(m.config_text(), manifest.string() + " config_text"));
  r.dir = dir;
  r.manifest = m;
  r.policy = export_policy(r.config, r.task->spec(), dir, r.manifest.policy_version(), &r.updates);
  return r;
}

}  // namespace farm::tools
