// The policy file of a checkpoint (policy_file.h): PolicyParams <-> a binary Protobuf PolicyFile.
#include "policy_file.h"

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <vector>

#include "policy_file.pb.h"

namespace farm {

namespace fs = std::filesystem;

namespace {

// Far above any network of the farm (a few MB), far below what would exhaust memory.
constexpr std::uintmax_t kMaxPolicyFileBytes = 256u << 20;

}  // namespace

void write_policy_file(const std::string& path, const PolicyParams& p) {
  config::PolicyFile f;
  f.set_version(p.version);
  f.set_head(static_cast<int32_t>(p.head));
  f.set_activation(static_cast<int32_t>(p.layout.activation));
  *f.mutable_layer_sizes() = {p.layout.sizes.begin(), p.layout.sizes.end()};
  *f.mutable_parameters() = {p.params.begin(), p.params.end()};
  *f.mutable_obs_mean() = {p.obs_mean.begin(), p.obs_mean.end()};
  *f.mutable_obs_std() = {p.obs_std.begin(), p.obs_std.end()};
  f.set_log_std_min(p.log_std_min);
  f.set_log_std_max(p.log_std_max);
  f.set_epsilon(p.epsilon);
  *f.mutable_log_std() = {p.log_std.begin(), p.log_std.end()};
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    if (!out || !f.SerializeToOstream(&out) || (out.close(), !out)) {
      std::remove(tmp.c_str());
      throw std::runtime_error("cannot write the policy file " + path);
    }
  }
  std::error_code ec;
  fs::rename(tmp, path, ec);
  if (ec) {
    std::remove(tmp.c_str());
    throw std::runtime_error("cannot write the policy file " + path + ": " + ec.message());
  }
}

PolicyParams read_policy_file(const std::string& path) {
  const auto bad = [&](const std::string& why) { return std::runtime_error("policy file " + path + ": " + why); };
  std::error_code ec;
  if (!fs::exists(path, ec)) throw bad("does not exist");
  const std::uintmax_t size = fs::file_size(path, ec);
  if (ec) throw bad("cannot be read: " + ec.message());
  if (size > kMaxPolicyFileBytes)
    throw bad(std::to_string(size) + " bytes, more than a policy file's limit of " +
              std::to_string(kMaxPolicyFileBytes));
  std::ifstream in(path, std::ios::binary);
  std::stringstream bytes;
  bytes << in.rdbuf();
  if (!in) throw bad("cannot be read");
  config::PolicyFile f;
  if (!f.ParseFromString(bytes.str())) throw bad("not a PolicyFile (policy_file.proto)");
  if (!f.has_head() || !f.has_activation() || f.layer_sizes().empty())
    throw bad("no head, activation or layer sizes: not a policy written by the learner");
  if (!activation_known(f.activation()))
    throw bad("unknown activation " + std::to_string(f.activation()) + " (expected 0 relu, 1 tanh or 2 elu)");
  PolicyParams p;
  p.version = f.version();
  p.head = static_cast<PolicyHead>(f.head());
  p.layout.activation = static_cast<Activation>(f.activation());
  p.layout.sizes.assign(f.layer_sizes().begin(), f.layer_sizes().end());
  p.params.assign(f.parameters().begin(), f.parameters().end());
  p.obs_mean.assign(f.obs_mean().begin(), f.obs_mean().end());
  p.obs_std.assign(f.obs_std().begin(), f.obs_std().end());
  p.log_std_min = f.log_std_min();
  p.log_std_max = f.log_std_max();
  p.epsilon = f.epsilon();
  p.log_std.assign(f.log_std().begin(), f.log_std().end());
  try {
    Policy check(p);  // the sizes, head, finiteness and normalizer checks a worker makes of weights off the wire
  } catch (const std::invalid_argument& e) {
    throw bad(e.what());
  }
  return p;
}

}  // namespace farm
