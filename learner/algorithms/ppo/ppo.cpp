#include "ppo.h"
#include "archive_io.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <stdexcept>

#include "compute.h"
#include "config.h"
#include "policy_shape.h"

namespace farm {

namespace {

constexpr double kHalfLog2Pi = 0.91893853320467274178;
// The most |log pi - log pi_old| a step's ratio is taken at (e^20: about 5e8).
constexpr double kMaxLogRatio = 20.0;

struct MlpImpl : torch::nn::Module {
  MlpImpl(const std::vector<int64_t>& sizes, Activation hidden_activation, double last_gain)
      : hidden_activation(hidden_activation) {
    for (size_t i = 0; i + 1 < sizes.size(); ++i)
      layers.push_back(register_module("l" + std::to_string(i), torch::nn::Linear(sizes[i], sizes[i + 1])));
    // A small last layer starts the policy near mean 0 (actions centred, exploration from the
    // log-std alone) and the value near 0.
    torch::NoGradGuard g;
    layers.back()->weight.mul_(last_gain);
    layers.back()->bias.zero_();
  }
  torch::Tensor forward(torch::Tensor x) {
    for (size_t i = 0; i < layers.size(); ++i) {
      x = layers[i]->forward(x);
      if (i + 1 < layers.size()) x = activate(x);
    }
    return x;
  }
  // The hidden layers' activation, as the workers' kernel computes it (common/mlp_kernel.cpp).
  torch::Tensor activate(const torch::Tensor& x) const {
    switch (hidden_activation) {
      case Activation::kTanh:
        return torch::tanh(x);
      case Activation::kElu:
        return torch::elu(x);  // alpha 1
      case Activation::kRelu:
        break;
    }
    return torch::relu(x);
  }
  std::vector<torch::nn::Linear> layers;
  Activation hidden_activation;
};
TORCH_MODULE(Mlp);

torch::Tensor from_floats(const float* p, int64_t rows, int64_t cols) {
  return torch::from_blob(const_cast<float*>(p), {rows, cols}, torch::kFloat32).clone();
}

}  // namespace

double adapt_learning_rate(double lr, double kl, const config::PpoConfig& c) {
  if (!std::isfinite(kl)) return lr;
  if (kl > c.kl_band() * c.desired_kl())
    lr /= c.lr_factor();
  else if (kl < c.desired_kl() / c.kl_band())
    lr *= c.lr_factor();
  return std::clamp(lr, c.lr_min(), c.lr_max());
}

struct Ppo::Impl {
  config::PpoConfig cfg;
  int obs_dim, act_dim;
  std::vector<int> hidden;
  mutable Mlp actor{nullptr}, critic{nullptr};
  torch::Tensor log_std;
  std::unique_ptr<torch::optim::Adam> opt;
  ObsNormalizer norm;
  torch::Device device{torch::kCPU};  // where the networks and a fit's data live
  double lr;
  int64_t fits = 0, updates = 0;

  torch::Tensor normalize(const float* obs, int64_t n) const {
    torch::Tensor x = from_floats(obs, n, obs_dim);
    if (cfg.normalize_observations()) {
      auto m = norm.mean(), s = norm.std();
      x = (x - torch::from_blob(m.data(), {1, obs_dim}).clone()) / torch::from_blob(s.data(), {1, obs_dim}).clone();
    }
    return x.to(device);
  }
  torch::Tensor clamped_log_std() const { return log_std.clamp(cfg.log_std_min(), cfg.log_std_max()); }
  // Sum over action dims of the clipped Gaussian's log-probability (as the workers compute it,
  // common/mlp.h kGaussian): the density inside (-1, 1), the mass beyond a bound at the bound.
  static torch::Tensor log_prob(const torch::Tensor& mean, const torch::Tensor& ls, const torch::Tensor& a) {
    const auto inv_std = torch::exp(-ls);
    const auto z = (a - mean) * inv_std;
    const auto inside = -0.5 * z * z - ls - kHalfLog2Pi;
    const auto upper = torch::special::log_ndtr((mean - 1.0) * inv_std);
    const auto lower = torch::special::log_ndtr((-1.0 - mean) * inv_std);
    return torch::where(a >= 1.0, upper, torch::where(a <= -1.0, lower, inside)).sum(-1);
  }
  void set_lr(double v) {
    lr = v;
    for (auto& g : opt->param_groups()) static_cast<torch::optim::AdamOptions&>(g.options()).lr(v);
  }
};

Ppo::Ppo(const config::PpoConfig& cfg, int obs_dim, int act_dim, uint64_t seed) : impl_(std::make_unique<Impl>()) {
  check_config(cfg);  // the loader's checks, for a config built in code
  if (obs_dim <= 0 || act_dim <= 0) throw std::invalid_argument("Ppo: obs_dim and act_dim must be > 0");
  Impl& s = *impl_;
  torch::manual_seed(seed);
  s.cfg = cfg;
  s.obs_dim = obs_dim;
  s.act_dim = act_dim;
  s.hidden = ppo_hidden(cfg);
  std::vector<int64_t> a{obs_dim}, v{obs_dim};
  for (int h : s.hidden) {
    a.push_back(h);
    v.push_back(h);
  }
  a.push_back(act_dim);
  v.push_back(1);
  const Activation act = activation_from_name(cfg.activation());  // checked by the config
  s.actor = Mlp(a, act, 0.01);  // initialized on the host, so a seed gives the same nets everywhere
  s.critic = Mlp(v, act, 1.0);
  s.device = learner_device(cfg.device(), "ppo.device");
  s.actor->to(s.device);
  s.critic->to(s.device);
  s.log_std =
      torch::full({act_dim}, cfg.initial_log_std(), torch::TensorOptions().device(s.device).requires_grad(true));
  std::vector<torch::Tensor> params = s.actor->parameters();
  for (auto& p : s.critic->parameters()) params.push_back(p);
  params.push_back(s.log_std);
  s.lr = cfg.learning_rate();
  s.opt = std::make_unique<torch::optim::Adam>(params, torch::optim::AdamOptions(s.lr));
  s.norm = ObsNormalizer(obs_dim);
}

Ppo::~Ppo() = default;

std::vector<float> Ppo::values(const float* obs, int64_t n) const {
  torch::NoGradGuard g;
  if (n == 0) return {};
  auto v = impl_->critic->forward(impl_->normalize(obs, n)).reshape({n}).cpu().contiguous();
  return {v.data_ptr<float>(), v.data_ptr<float>() + n};
}

std::vector<float> Ppo::log_probs(const float* obs, const float* actions, int64_t n) const {
  torch::NoGradGuard g;
  if (n == 0) return {};
  // Non-const: LibTorch 2.x's const ModuleHolder gives only const access, and forward() is not.
  Impl& s = *impl_;
  auto mean = s.actor->forward(s.normalize(obs, n));
  auto lp =
      Impl::log_prob(mean, s.clamped_log_std(), from_floats(actions, n, s.act_dim).to(s.device)).cpu().contiguous();
  return {lp.data_ptr<float>(), lp.data_ptr<float>() + n};
}

PpoStats Ppo::fit(const PpoSamples& d) {
  Impl& s = *impl_;
  const int64_t n = d.n;
  PpoStats st;
  st.samples = n;
  if (n == 0) {
    st.learning_rate = s.lr;
    return st;
  }
  const bool clip_kl = s.cfg.variant() == "clip_kl";
  const auto X = s.normalize(d.obs.data(), n);
  const auto A = from_floats(d.actions.data(), n, s.act_dim).to(s.device);
  torch::Tensor old_mean, old_ls, old_lp;
  torch::Tensor weight;  // "proximal": each step's weight in the surrogate (undefined: all 1)
  {
    torch::NoGradGuard g;
    old_mean = s.actor->forward(X);
    old_ls = s.clamped_log_std().clone();
    const auto recomputed = Impl::log_prob(old_mean, old_ls, A);
    const auto behaviour = from_floats(d.behaviour_log_prob.data(), n, 1).reshape({n}).to(s.device);
    const auto cur =
        torch::from_blob(const_cast<uint8_t*>(d.current.data()), {n}, torch::kUInt8).to(s.device).to(torch::kBool);
    if (s.cfg.surrogate() == "proximal") {
      old_lp = recomputed;
      // min(rho_bar, pi_start / pi_behaviour), the exponent clamped first so it cannot overflow.
      const auto w = torch::exp(torch::clamp_max(recomputed - behaviour, std::log(s.cfg.vtrace_rho_bar())));
      weight = torch::where(cur, torch::ones_like(w), w);
    } else {
      old_lp = torch::where(cur, recomputed, behaviour);
    }
  }
  auto adv = from_floats(d.advantages.data(), n, 1).reshape({n}).to(s.device);
  const auto ret = from_floats(d.returns.data(), n, 1).reshape({n}).to(s.device);
  if (s.cfg.normalize_advantages() && n > 1) adv = (adv - adv.mean()) / (adv.std() + 1e-8);

  const int64_t mb = std::min<int64_t>(s.cfg.mini_batch_size(), n);
  const double eps = s.cfg.clip_epsilon();
  std::vector<torch::Tensor> all_params = s.opt->param_groups()[0].params();
  for (int e = 0; e < s.cfg.epochs(); ++e) {
    const bool last_epoch = e + 1 == s.cfg.epochs();
    const auto perm = torch::randperm(n, torch::kLong).to(s.device);  // host generator: same order on any device
    double clipped = 0, vloss = 0, ploss = 0, gnorm = 0;
    int64_t batches = 0;
    for (int64_t b = 0; b < n; b += mb) {
      const auto idx = perm.slice(0, b, std::min(n, b + mb));
      const auto x = X.index_select(0, idx), a = A.index_select(0, idx);
      const auto mean = s.actor->forward(x);
      const auto ls = s.clamped_log_std();
      const auto lp = Impl::log_prob(mean, ls, a);
      // The log-ratio clamped before exp: a behaviour log-probability from a batch is finite but may
      // be absurd (-1e30), and exp of it would make the loss infinite. No step of a working run
      // comes near e^20, so nothing else changes.
      const auto ratio = torch::exp(torch::clamp(lp - old_lp.index_select(0, idx), -kMaxLogRatio, kMaxLogRatio));
      const auto ad = adv.index_select(0, idx);
      auto surr = torch::min(ratio * ad, torch::clamp(ratio, 1 - eps, 1 + eps) * ad);
      if (weight.defined()) surr = surr * weight.index_select(0, idx);
      const auto policy_loss = -surr.mean();
      const auto value_loss = (s.critic->forward(x).reshape({-1}) - ret.index_select(0, idx)).pow(2).mean();
      const auto entropy = (ls + 0.5 + kHalfLog2Pi).sum();
      const auto loss = policy_loss + s.cfg.value_loss_coef() * value_loss - s.cfg.entropy_coef() * entropy;
      s.opt->zero_grad();
      loss.backward();
      double norm = 0;
      if (clip_kl) norm = torch::nn::utils::clip_grad_norm_(all_params, s.cfg.max_grad_norm());
      s.opt->step();
      ++s.updates;
      ++st.minibatches;
      if (clip_kl) {
        // KL(old || new) of this mini-batch before its step, as the modified PPO measures it.
        torch::NoGradGuard g;
        const auto om = old_mean.index_select(0, idx);
        const auto kl = (ls - old_ls + (torch::exp(2 * old_ls) + (om - mean).pow(2)) / (2 * torch::exp(2 * ls)) - 0.5)
                            .sum(-1)
                            .mean()
                            .item<double>();
        s.set_lr(adapt_learning_rate(s.lr, kl, s.cfg));
      }
      if (last_epoch) {
        torch::NoGradGuard g;
        clipped += ((ratio - 1).abs() > eps).to(torch::kFloat32).sum().item<double>();
        vloss += value_loss.item<double>();
        ploss += policy_loss.item<double>();
        gnorm += norm;
        ++batches;
      }
    }
    if (last_epoch) {
      st.clip_fraction = clipped / double(n);
      st.value_loss = vloss / double(batches);
      st.policy_loss = ploss / double(batches);
      st.grad_norm = gnorm / double(batches);
    }
  }
  {
    torch::NoGradGuard g;
    const auto mean = s.actor->forward(X);
    const auto ls = s.clamped_log_std();
    st.kl = (ls - old_ls + (torch::exp(2 * old_ls) + (old_mean - mean).pow(2)) / (2 * torch::exp(2 * ls)) - 0.5)
                .sum(-1)
                .mean()
                .item<double>();
    st.entropy = (ls + 0.5 + kHalfLog2Pi).sum().item<double>();
  }
  st.learning_rate = s.lr;
  ++s.fits;
  return st;
}

PolicyParams Ppo::export_policy(uint64_t version) const {
  const Impl& s = *impl_;
  PolicyParams p = ppo_policy_shape(s.cfg, s.obs_dim, s.act_dim);
  p.version = version;
  for (auto& l : s.actor->layers) {
    auto w = l->weight.detach().cpu().contiguous(), b = l->bias.detach().cpu().contiguous();
    p.params.insert(p.params.end(), w.data_ptr<float>(), w.data_ptr<float>() + w.numel());
    p.params.insert(p.params.end(), b.data_ptr<float>(), b.data_ptr<float>() + b.numel());
  }
  auto ls = s.log_std.detach().cpu().contiguous();
  p.log_std.assign(ls.data_ptr<float>(), ls.data_ptr<float>() + ls.numel());
  if (s.cfg.normalize_observations()) {
    p.obs_mean = s.norm.mean();
    p.obs_std = s.norm.std();
  }
  return p;
}

ObsNormalizer& Ppo::normalizer() { return impl_->norm; }
const ObsNormalizer& Ppo::normalizer() const { return impl_->norm; }
double Ppo::learning_rate() const { return impl_->lr; }
torch::Device Ppo::device() const { return impl_->device; }
int64_t Ppo::fits() const { return impl_->fits; }
int64_t Ppo::updates() const { return impl_->updates; }

void Ppo::save(const std::string& dir) const {
  const Impl& s = *impl_;
  std::filesystem::create_directories(dir);  // as Sac::save: the folder need not exist yet
  torch::serialize::OutputArchive ar;
  torch::serialize::OutputArchive actor, critic, optim;
  s.actor->save(actor);
  s.critic->save(critic);
  s.opt->save(optim);
  ar.write("actor", actor);
  ar.write("critic", critic);
  ar.write("optimizer", optim);
  ar.write("log_std", s.log_std.detach());
  const auto& m = s.norm.raw_mean();
  const auto& m2 = s.norm.raw_m2();
  ar.write("norm_mean", torch::tensor(std::vector<double>(m.begin(), m.end()), torch::kFloat64));
  ar.write("norm_m2", torch::tensor(std::vector<double>(m2.begin(), m2.end()), torch::kFloat64));
  ar.write("norm_count", torch::tensor(s.norm.count(), torch::kFloat64));
  ar.write("lr", torch::tensor(s.lr, torch::kFloat64));
  ar.write("activation", torch::tensor(int64_t(s.actor->hidden_activation), torch::kLong));
  ar.write("counts", torch::tensor(std::vector<int64_t>{s.fits, s.updates}, torch::kLong));
  const std::string path = (std::filesystem::path(dir) / "ppo.pt").string();
  save_archive(ar, path + ".tmp");
  std::filesystem::rename(path + ".tmp", path);
}

void Ppo::load(const std::string& dir) {
  Impl& s = *impl_;
  const std::string path = (std::filesystem::path(dir) / "ppo.pt").string();
  try {
    torch::serialize::InputArchive ar;
    // Tensors land on this learner's device whatever device wrote them: a GPU run's checkpoint is
    // read by the CPU programs around it (farm-play, farm-export) and by a CPU learner's --resume.
    ar.load_from(path, s.device);
    // Module::load takes a saved tensor's shape as it is: the shapes this config makes are kept
    // and compared, so networks of other hidden sizes are refused rather than run half-sized.
    const auto shapes = [&] {
      std::vector<std::pair<std::string, std::vector<int64_t>>> out;
      for (const auto& [net, m] : {std::pair<const char*, Mlp&>{"actor", s.actor}, {"critic", s.critic}})
        for (const auto& p : m->named_parameters()) out.emplace_back(net + ("." + p.key()), p.value().sizes().vec());
      return out;
    };
    const auto want = shapes();
    torch::Tensor act;
    if (ar.try_read("activation", act) && act.item<int64_t>() != int64_t(s.actor->hidden_activation))
      throw std::runtime_error("its networks use another activation than this config's ppo.activation '" +
                               s.cfg.activation() + "'");
    torch::serialize::InputArchive actor, critic, optim;
    ar.read("actor", actor);
    ar.read("critic", critic);
    ar.read("optimizer", optim);
    s.actor->load(actor);
    s.critic->load(critic);
    const auto got = shapes();
    for (size_t i = 0; i < want.size(); ++i)
      if (got[i].second != want[i].second)
        throw std::runtime_error(got[i].first + " has shape " + shape_str(got[i].second) + ", this config's " +
                                 "ppo.hidden makes " + shape_str(want[i].second));
    s.actor->to(s.device);  // a checkpoint from another device
    s.critic->to(s.device);
    s.opt->load(optim);
    torch::Tensor ls, nm, nm2, nc, lr, counts;
    ar.read("log_std", ls);
    ar.read("norm_mean", nm);
    ar.read("norm_m2", nm2);
    ar.read("norm_count", nc);
    ar.read("lr", lr);
    ar.read("counts", counts);
    if (ls.numel() != s.act_dim || nm.numel() != s.obs_dim)
      throw std::runtime_error("log_std or normalizer size does not match this task");
    {
      torch::NoGradGuard g;
      s.log_std.copy_(ls);
    }
    // Loaded onto s.device: the normalizer's moments are read on the host, not from GPU memory.
    nm = nm.to(torch::kCPU).contiguous();
    nm2 = nm2.to(torch::kCPU).contiguous();
    s.norm.set_state(nc.item<double>(), {nm.data_ptr<double>(), nm.data_ptr<double>() + s.obs_dim},
                     {nm2.data_ptr<double>(), nm2.data_ptr<double>() + s.obs_dim});
    // The adapted rate of clip_kl goes on from where it was, within this config's bounds; the
    // plain variant's rate is the config's, as SAC's and DQN's are.
    s.set_lr(s.cfg.variant() == "clip_kl" ? std::clamp(lr.item<double>(), s.cfg.lr_min(), s.cfg.lr_max())
                                          : s.cfg.learning_rate());
    s.fits = counts[0].item<int64_t>();
    s.updates = counts[1].item<int64_t>();
  } catch (const c10::Error& e) {
    throw std::runtime_error(path + ": " + e.what_without_backtrace());
  } catch (const std::runtime_error& e) {
    throw std::runtime_error(path + ": " + e.what());
  }
}

}  // namespace farm
