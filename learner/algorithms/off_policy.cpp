#include "off_policy.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "dqn.h"
#include "sac.h"

namespace farm {

namespace {

class SacAlgorithm final : public OffPolicy {
 public:
  SacAlgorithm(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec)
      : cfg_(cfg.sac()), sac_(cfg.sac(), spec.obs_dim, spec.act_dim, cfg.seed()) {}
  std::string name() const override { return "sac"; }
  OffPolicyStats update(const SampledBatch& b) override { return figures(sac_.update(b)); }
  std::vector<OffPolicyStats> update_n(int n, const std::function<SampledBatch()>& next_batch) override {
    return all_figures(sac_.update_n(n, next_batch));
  }
  std::optional<torch::Device> replay_device() const override {
    if (cfg_.replay_on_device() && sac_.uses_cuda_graph()) return sac_.device();
    return std::nullopt;
  }
  std::vector<OffPolicyStats> update_n_from(int n, const DeviceReplay& replay) override {
    return all_figures(sac_.update_n_from(n, batch_size(), replay));
  }
  int64_t updates_in_flight() const override { return sac_.updates_in_flight(); }
  std::vector<OffPolicyStats> finish_updates() override { return all_figures(sac_.finish_updates()); }
  PolicyParams export_policy(uint64_t v) const override { return sac_.export_policy(v); }
  int64_t updates() const override { return sac_.updates(); }
  void save(const std::string& dir) const override { sac_.save(dir); }
  void load(const std::string& dir) override { sac_.load(dir); }
  int batch_size() const override { return cfg_.batch_size() * step_scale_; }
  int64_t buffer_size() const override { return cfg_.buffer_size(); }
  int64_t learning_starts() const override { return cfg_.learning_starts(); }
  double max_updates_per_step() const override { return cfg_.max_updates_per_step(); }
  int publish_every_updates() const override { return cfg_.publish_every_updates(); }
  // On a GPU only: there a batch of 1024 costs little more than one of 256, while on a CPU it
  // costs 2.3-3.4 times as much (sac.max_step_scale).
  int max_step_scale() const override { return sac_.on_gpu() ? cfg_.max_step_scale() : 1; }
  int step_scale() const override { return step_scale_; }
  void set_step_scale(int s) override {
    step_scale_ = s;
    sac_.scale_learning_rates(std::sqrt(double(s)));
  }
  double gamma() const override { return cfg_.gamma(); }
  int n_step() const override { return cfg_.n_step(); }
  std::string describe() const override {
    std::string step = cfg_.n_step() > 1 ? ", " + std::to_string(cfg_.n_step()) + "-step returns" : "";
    if (cfg_.max_step_scale() > 1)
      step += sac_.on_gpu()
                  ? ", step up to x" + std::to_string(cfg_.max_step_scale()) + " where the data outrun the updates"
                  : ", the seed's step (sac.max_step_scale is for a GPU learner)";
    if (sac_.uses_cuda_graph())
      step += sac_.uses_fused_kernels() ? ", CUDA graph with fused kernels" : ", CUDA graph of torch's ops";
    if (replay_device()) step += ", minibatches drawn on the GPU";
    return "SAC " + sac_.export_policy(0).layout.describe() + " actor" + step;
  }

 private:
  static OffPolicyStats figures(const SacStats& s) { return {s.critic_loss, s.actor_loss, s.alpha}; }
  static std::vector<OffPolicyStats> all_figures(const std::vector<SacStats>& stats) {
    std::vector<OffPolicyStats> out;
    out.reserve(stats.size());
    for (const SacStats& s : stats) out.push_back(figures(s));
    return out;
  }
  config::SacConfig cfg_;
  Sac sac_;
  int step_scale_ = 1;
};

class DqnAlgorithm final : public OffPolicy {
 public:
  DqnAlgorithm(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec)
      : cfg_(cfg.dqn()), dqn_(cfg.dqn(), spec.obs_dim, spec.num_actions, cfg.seed()) {}
  std::string name() const override { return "dqn"; }
  std::string alpha_name() const override { return "epsilon"; }
  OffPolicyStats update(const SampledBatch& b) override {
    const DqnStats s = dqn_.update(b);
    return {s.loss, 0.0, dqn_.epsilon()};
  }
  PolicyParams export_policy(uint64_t v) const override { return dqn_.export_policy(v); }
  int64_t updates() const override { return dqn_.updates(); }
  void set_env_steps(int64_t n) override { dqn_.set_env_steps(n); }
  void save(const std::string& dir) const override { dqn_.save(dir); }
  void load(const std::string& dir) override { dqn_.load(dir); }
  int batch_size() const override { return cfg_.batch_size(); }
  int64_t buffer_size() const override { return cfg_.buffer_size(); }
  int64_t learning_starts() const override { return cfg_.learning_starts(); }
  double max_updates_per_step() const override { return cfg_.max_updates_per_step(); }
  int publish_every_updates() const override { return cfg_.publish_every_updates(); }
  int n_step() const override { return cfg_.n_step(); }
  double gamma() const override { return cfg_.gamma(); }
  std::string describe() const override {
    return std::string(cfg_.double_q() ? "double DQN " : "DQN ") + dqn_.export_policy(0).layout.describe() +
           " Q network" + (cfg_.n_step() > 1 ? ", " + std::to_string(cfg_.n_step()) + "-step returns" : "") +
           (dqn_.uses_cuda_graph() ? ", CUDA graph"
            : dqn_.on_gpu()        ? ", on the GPU"
                                   : "");
  }

 private:
  config::DqnConfig cfg_;
  Dqn dqn_;
};

}  // namespace

int next_step_scale(int current, double r, int most) {
  int cap = 1;  // the largest power of 2 at most `most`
  while (cap <= most / 2) cap *= 2;
  // The power of 2 nearest r on a log scale (s for r from s / sqrt(2) to s * sqrt(2)), within cap:
  // a floor would take x2 where r is 3-4, which leaves half of what a step of x4 would use.
  int fit = 1;
  while (fit < cap && 2.0 * fit <= M_SQRT2 * r) fit *= 2;
  current = std::clamp(current, 1, cap);
  if (fit > current) return fit;
  if (r < 0.8 * current / M_SQRT2) return fit;  // down only past a margin below the step's band
  return current;
}

std::unique_ptr<OffPolicy> make_sac(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec) {
  if (spec.num_actions > 0) {
    throw std::invalid_argument("algorithm \"sac\" needs continuous actions, but task '" + spec.name + "' has " +
                                std::to_string(spec.num_actions) +
                                " discrete ones (set its scene.discrete_actions: false, or use algorithm \"dqn\")");
  }
  return std::make_unique<SacAlgorithm>(cfg, spec);
}

std::unique_ptr<OffPolicy> make_dqn(const config::ExperimentConfig& cfg, const robots::TaskSpec& spec) {
  if (spec.num_actions == 0) {
    throw std::invalid_argument("algorithm \"dqn\" needs discrete actions, but task '" + spec.name +
                                "' has continuous ones");
  }
  return std::make_unique<DqnAlgorithm>(cfg, spec);
}

}  // namespace farm
