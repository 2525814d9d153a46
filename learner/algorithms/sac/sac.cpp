#include "sac.h"
#include "archive_io.h"
#include "compute.h"
#include "device_replay.h"
#include "sac_impl.h"

#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <sstream>
#include <stdexcept>
#include <utility>

#include "config.h"
#include "policy_shape.h"

#include <ATen/Context.h>

// FARM_CUDA_GRAPHS: defined by learner/algorithms/CMakeLists.txt when LibTorch has CUDA. Without
// it (CPU LibTorch) every update runs eagerly, on whatever device the config names.

namespace farm {

namespace {

using namespace sac_detail;

}  // namespace

torch::Tensor sac_critic_target(const torch::Tensor& reward, const torch::Tensor& terminated,
                                const torch::Tensor& next_q1, const torch::Tensor& next_q2,
                                const torch::Tensor& next_log_prob, double alpha, double gamma) {
  auto soft_v = torch::min(next_q1, next_q2).sub_(next_log_prob, alpha);
  return torch::addcmul(reward, soft_v, 1.0 - terminated, gamma);
}

torch::Tensor sac_temperature_loss(const torch::Tensor& log_alpha, const torch::Tensor& log_prob,
                                   double target_entropy) {
  return -(log_alpha * (log_prob + target_entropy).detach()).mean();
}

torch::Tensor squashed_gaussian_log_prob(const torch::Tensor& mean, const torch::Tensor& log_std,
                                         const torch::Tensor& pre_tanh) {
  static const double kHalfLog2Pi = 0.5 * std::log(2.0 * M_PI);
  const auto z = (pre_tanh - mean) * torch::exp(-log_std);
  const auto gaussian = -0.5 * z.square() - log_std - kHalfLog2Pi;
  const auto squash = torch::log(1.0 - torch::tanh(pre_tanh).square() + 1e-6);
  return (gaussian - squash).sum(-1);
}

static const config::SacConfig& seeded(const config::SacConfig& cfg, uint64_t seed) {
  torch::manual_seed(seed);
  return cfg;
}

Sac::Sac(const config::SacConfig& cfg, int obs_dim, int act_dim, uint64_t seed)
    : impl_(std::make_unique<Impl>(seeded(cfg, seed), obs_dim, act_dim)) {
  // A process-wide switch in LibTorch: set by each SAC on CUDA, before its first update (and capture).
  if (impl_->device.is_cuda()) at::globalContext().setAllowTF32CuBLAS(cfg.cuda_tf32());
}
Sac::~Sac() = default;
Sac::Sac(Sac&&) noexcept = default;
Sac& Sac::operator=(Sac&&) noexcept = default;

std::vector<SacStats> Sac::update_n(int n, const std::function<SampledBatch()>& next_batch) {
  if (impl_->use_graph()) {
    const double gamma = impl_->cfg.gamma();
    auto out = impl_->graph_update_n(n, [&] { return fold_horizon(next_batch(), gamma); });
    impl_->average_policy(n);
    return out;
  }
  std::vector<SacStats> out;
  out.reserve(n);
  for (int i = 0; i < n; ++i) out.push_back(update(next_batch()));
  return out;
}

std::vector<SacStats> Sac::update_n_from(int n, int64_t batch, const DeviceReplay& replay) {
  require_same_device(replay, impl_->device, "sac");
  if (impl_->use_graph()) {
    auto out = impl_->graph_update_n_from(n, batch, replay);
    impl_->average_policy(n);
    return out;
  }
  return update_n(n, [&] { return replay.sample(batch); });
}

void Sac::scale_learning_rates(double factor) {
  if (!(factor > 0) || !std::isfinite(factor))
    throw std::invalid_argument("sac: learning-rate scale must be a finite number > 0, got " + std::to_string(factor));
  if (factor == impl_->lr_scale) return;
  impl_->lr_scale = factor;
  impl_->apply_learning_rates();
}

double Sac::learning_rate_scale() const { return impl_->lr_scale; }

int64_t Sac::updates_in_flight() const { return impl_->updates_in_flight(); }
std::vector<SacStats> Sac::finish_updates() { return impl_->finish_updates(); }

SacStats Sac::update(const SampledBatch& sampled) {
  Impl& s = *impl_;
  // Multi-step rows (sac.n_step): their horizon folded into `terminated`, so that the one target
  // r + gamma * (1 - terminated) * v below (and in the graph) bootstraps with gamma^h.
  const SampledBatch host_batch = fold_horizon(sampled, s.cfg.gamma());
  if (s.use_graph()) {
    const SacStats st = s.graph_update(host_batch);
    s.average_policy(1);
    return st;
  }
  SacStats st;
  // On the CPU these are the same tensors; on a GPU, one copy of the minibatch per update.
  SampledBatch batch;
  if (s.device.is_cpu()) {
    batch = host_batch;
  } else {
    batch = {host_batch.obs.to(s.device), host_batch.actions.to(s.device), host_batch.rewards.to(s.device),
             host_batch.terminated.to(s.device), host_batch.next_obs.to(s.device)};
  }
  auto [pi_action, log_prob] = s.sample(batch.obs);

  // sb3 order: the temperature used by both losses is the one before this update's alpha step.
  const double alpha = std::exp(s.log_alpha.item<double>());
  const auto alpha_loss = sac_temperature_loss(s.log_alpha, log_prob, s.target_entropy);
  step(*s.alpha_opt, s.log_alpha, alpha_loss);

  torch::Tensor target;
  {
    torch::NoGradGuard no_grad;
    auto [next_action, next_log_prob] = s.sample(batch.next_obs);
    const auto next_q = s.critic_target->forward(batch.next_obs, next_action);
    target =
        sac_critic_target(batch.rewards, batch.terminated, next_q[0], next_q[1], next_log_prob, alpha, s.cfg.gamma());
  }
  torch::Tensor actor_loss;
  auto actor_step = [&] {
    const auto q_pi = s.critic->forward(batch.obs, pi_action);
    actor_loss = (alpha * log_prob - torch::min(q_pi[0], q_pi[1])).mean();
    step(*s.actor_opt, s.actor_p, actor_loss);
  };
  // sac.actor_on_previous_critic: the actor's step against the critics before theirs. The critic
  // target above was drawn from the actor before its step either way.
  if (s.cfg.actor_on_previous_critic()) actor_step();

  const auto q = s.critic->forward(batch.obs, batch.actions);
  // Mean over both critics' rows = sb3's 0.5 * (mse(q1) + mse(q2)).
  const auto critic_loss = torch::mse_loss(q, target.unsqueeze(0).expand_as(q));
  step(*s.critic_opt, s.critic_p, critic_loss);

  if (!s.cfg.actor_on_previous_critic()) actor_step();

  {
    torch::NoGradGuard no_grad;
    // target + tau * (online - target) = (1 - tau) * target + tau * online, in one op.
    s.target_p.flat.lerp_(s.critic_p.flat, s.cfg.tau());
    // One read-back for all five figures: on a GPU each item() is a synchronization.
    const auto figures = torch::stack({critic_loss.reshape({}), actor_loss.reshape({}), alpha_loss.reshape({}),
                                       -log_prob.mean(), q.mean()})
                             .to(torch::kCPU, torch::kDouble);
    const double* f = figures.data_ptr<double>();
    st.critic_loss = f[0];
    st.actor_loss = f[1];
    st.alpha_loss = f[2];
    st.entropy = f[3];
    st.q_mean = f[4];
  }
  st.alpha = alpha;
  ++s.updates;
  s.average_policy(1);
  return st;
}

PolicyParams Sac::export_policy(uint64_t version) const {
  const Impl& s = *impl_;
  PolicyParams p = sac_policy_shape(s.cfg, s.obs_dim, s.act_dim);
  p.version = version;
  // The actor's flat buffer is already in the workers' order: per layer, weight [out x in]
  // row-major, then bias.
  const torch::Tensor flat =
      (s.policy_average.defined() ? s.policy_average : s.actor_p.flat).detach().to(torch::kCPU).contiguous();
  const float* d = flat.data_ptr<float>();
  p.params.assign(d, d + flat.numel());
  return p;
}

int64_t Sac::updates() const { return impl_->updates; }
bool Sac::uses_cuda_graph() const { return impl_->use_graph(); }
bool Sac::uses_fused_kernels() const { return impl_->use_fused_kernels(); }
bool Sac::on_gpu() const { return impl_->device.is_cuda(); }
torch::Device Sac::device() const { return impl_->device; }
int Sac::obs_dim() const { return impl_->obs_dim; }
int Sac::act_dim() const { return impl_->act_dim; }
const std::vector<int>& Sac::hidden() const { return impl_->hidden; }
double Sac::alpha() const { return std::exp(impl_->log_alpha.item<double>()); }
double Sac::target_entropy() const { return impl_->target_entropy; }

torch::Tensor Sac::deterministic_action(const torch::Tensor& obs) const {
  torch::NoGradGuard no_grad;
  const auto x = obs.to(impl_->device);
  return torch::tanh(impl_->actor->forward(x).narrow(1, 0, impl_->act_dim)).to(obs.device());
}

std::vector<torch::Tensor> Sac::actor_parameters() const { return impl_->actor_p.params; }
std::vector<torch::Tensor> Sac::critic_parameters() const { return impl_->critic_p.params; }
std::vector<torch::Tensor> Sac::target_critic_parameters() const { return impl_->target_p.params; }

void Sac::save(const std::string& dir) const {
  const Impl& s = *impl_;
  std::filesystem::create_directories(dir);
  const std::string file = dir + "/sac.pt", tmp = file + ".tmp";
  try {
    torch::serialize::OutputArchive root;
    std::vector<int64_t> meta{s.obs_dim, s.act_dim};
    meta.insert(meta.end(), s.hidden.begin(), s.hidden.end());
    root.write("meta", torch::tensor(meta, torch::kInt64));
    root.write("activation", torch::tensor(int64_t(s.actor->tanh_hidden), torch::kInt64));  // 1: tanh, 0: relu
    write_params(root, "actor", *s.actor);
    write_params(root, "critic", *s.critic);
    write_params(root, "critic_target", *s.critic_target);
    const std::pair<const char*, torch::optim::Optimizer*> opts[] = {
        {"actor_optim", s.actor_opt.get()}, {"critic_optim", s.critic_opt.get()}, {"alpha_optim", s.alpha_opt.get()}};
    for (const auto& [key, opt] : opts) {
      torch::serialize::OutputArchive a;
      opt->save(a);
      root.write(key, a);
    }
    root.write("log_alpha", s.log_alpha.detach());
    root.write("updates", torch::full({1}, s.updates, torch::kInt64));
    if (s.policy_average.defined()) root.write("policy_average", s.policy_average.detach());
    save_archive(root, tmp);
  } catch (const c10::Error& e) {
    throw std::runtime_error("sac checkpoint " + tmp + ": " + e.what_without_backtrace());
  }
  if (std::rename(tmp.c_str(), file.c_str()) != 0)
    throw std::runtime_error("sac checkpoint " + file + ": cannot rename " + tmp + " to it");
}

void Sac::load(const std::string& dir) {
  Impl& s = *impl_;
  // Queued replays finish before their tensors are replaced; their figures belong to the state
  // being replaced and go with it. The graph goes too, before the optimizers' state it holds is
  // replaced: also where the load fails half way (the next update captures anew).
  s.drop_graph();
  s.ready.clear();
  const std::string file = dir + "/sac.pt";
  auto fail = [&](const std::string& what) { return std::runtime_error("sac checkpoint " + file + ": " + what); };
  try {
    torch::serialize::InputArchive root;
    root.load_from(file, s.device);  // whatever device wrote it (a GPU run read on a CPU host)

    torch::Tensor meta;
    if (!root.try_read("meta", meta)) throw fail("no 'meta'");
    std::vector<int64_t> want{s.obs_dim, s.act_dim};
    want.insert(want.end(), s.hidden.begin(), s.hidden.end());
    meta = meta.to(torch::kCPU).contiguous();  // loaded onto s.device: read on the host, not from GPU memory
    const int64_t* m = meta.data_ptr<int64_t>();
    const std::vector<int64_t> got(m, m + meta.numel());
    if (got != want) throw fail("networks are obs,act,hidden = " + sizes_str(got) + ", expected " + sizes_str(want));
    // Absent from checkpoints written before it was recorded: those are taken as they are.
    torch::Tensor tanh;
    if (root.try_read("activation", tanh) && tanh.item<int64_t>() != int64_t(s.actor->tanh_hidden))
      throw fail("its networks use another activation than this config's sac.activation '" + s.cfg.activation() + "'");

    const auto actor = read_params(root, "actor", *s.actor, "sac checkpoint", file);
    const auto critic = read_params(root, "critic", *s.critic, "sac checkpoint", file);
    const auto target = read_params(root, "critic_target", *s.critic_target, "sac checkpoint", file);
    torch::Tensor log_alpha, updates;
    if (!root.try_read("log_alpha", log_alpha) || log_alpha.sizes() != s.log_alpha.sizes())
      throw fail("missing or misshapen 'log_alpha'");
    if (!root.try_read("updates", updates) || updates.numel() != 1) throw fail("missing or misshapen 'updates'");
    // Written where sac.policy_average_tau was on; without it the average starts again from the
    // actor at the next update.
    torch::Tensor average;
    if (root.try_read("policy_average", average) && average.sizes() != s.actor_p.flat.sizes())
      throw fail("misshapen 'policy_average'");
    torch::serialize::InputArchive actor_opt, critic_opt, alpha_opt;
    if (!root.try_read("actor_optim", actor_opt) || !root.try_read("critic_optim", critic_opt) ||
        !root.try_read("alpha_optim", alpha_opt))
      throw fail("missing optimizer state");

    copy_into(s.actor_p.params, actor);
    copy_into(s.critic_p.params, critic);
    copy_into(s.target_p.params, target);
    copy_into({s.log_alpha}, {log_alpha});
    s.actor_opt->load(actor_opt);
    s.critic_opt->load(critic_opt);
    s.alpha_opt->load(alpha_opt);
    s.updates = updates.item<int64_t>();
    s.policy_average =
        average.defined() && s.cfg.policy_average_tau() > 0 ? average.to(s.device).clone() : torch::Tensor();
    // The saved optimizers carry the learning rates they ran with; this run's are its own. Drops
    // the CUDA graph too: the optimizer state tensors it was captured with were replaced.
    s.apply_learning_rates();
  } catch (const c10::Error& e) {
    throw fail(e.what_without_backtrace());
  }
}

}  // namespace farm
