// The loader of a run's policy (run_policy.h): the checkpoint manifest, bounded and parsed with the
// parser's first complaint, the task it names and the policy file beside it.
#include "run_policy.h"

#include <google/protobuf/io/tokenizer.h>
#include <google/protobuf/text_format.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

#include "config.h"
#include "policy_file.h"
#include "task_specs.h"

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

}  // namespace

void check_fits(const PolicyParams& p, const robots::TaskSpec& spec, const std::string& file) {
  const int in = p.layout.sizes.front(), out = p.layout.sizes.back();
  int want = spec.act_dim;
  if (p.head == PolicyHead::kSquashedGaussian) want = 2 * spec.act_dim;
  if (p.head == PolicyHead::kDiscreteQ) want = spec.num_actions;
  if (in != spec.obs_dim || out != want)
    throw std::runtime_error("policy file " + file + ": its network " + p.layout.describe() + " does not fit task " +
                             spec.name + " (" + std::to_string(spec.obs_dim) + " observations in, " +
                             std::to_string(want) + " outputs for its actions)");
}

RunPolicy with_task(config::ExperimentConfig cfg) {
  clear_output_paths(&cfg);
  RunPolicy r;
  r.config = std::move(cfg);
  r.task = robots::make_task(r.config.task());
  return r;
}

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
  RunPolicy r = with_task(robots::parse_config_text(m.config_text(), manifest.string() + " config_text"));
  r.dir = dir;
  r.manifest = m;
  const fs::path file = fs::path(dir) / kPolicyFileName;
  if (!fs::exists(file)) {
    std::string networks;  // a checkpoint of a learner that wrote no policy file still has these
    if (fs::exists(fs::path(dir) / r.config.algorithm()))
      networks = " (it holds the networks in " + (fs::path(dir) / r.config.algorithm()).string() + "/)";
    throw std::runtime_error("no policy file in " + dir + ": " + file.string() + " does not exist" + networks +
                             "; a learner of this version writes it with every checkpoint and best policy: write it "
                             "for this folder with `farm-policy-file " +
                             dir +
                             "`, or resume the run once (farm-learner --resume) to have it at its next checkpoint");
  }
  r.policy = read_policy_file(file.string());
  check_fits(r.policy, r.task->spec(), file.string());
  r.policy.version = r.manifest.policy_version();
  r.updates = r.manifest.updates();
  return r;
}

}  // namespace farm::tools
