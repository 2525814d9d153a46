#include "fastsac.h"

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <stdexcept>
#include <tuple>
#include <utility>

#include "archive_io.h"
#include "compute.h"
#include "config.h"
#include "device_minibatch.h"
#include "flat_params.h"
#include "obs_normalizer.h"
#include "policy_shape.h"
#include "sac.h"  // squashed_gaussian_log_prob
#include "td3.h"  // the C51 support, projection, expected value, loss and checkpoint record

namespace farm {

namespace {

// The actor: Linear layers in the workers' flat layout (weight.flatten() then bias per layer),
// fastsac.activation between them, output [mean | log_std]. The hidden layers keep
// torch::nn::Linear's default initialization (PyTorch's, as FastSAC's nn.Linear); the output layer
// starts with zero weights, zero mean bias and the log-std bias `log_std_init`.
struct ActorImpl : torch::nn::Module {
  ActorImpl(int obs, const std::vector<int>& hidden, int act, Activation activation, double log_std_init)
      : activation(activation) {
    int64_t in = obs;
    for (size_t i = 0; i <= hidden.size(); ++i) {
      const int64_t out = i < hidden.size() ? hidden[i] : 2 * act;
      layers.push_back(register_module("l" + std::to_string(i), torch::nn::Linear(in, out)));
      in = out;
    }
    torch::NoGradGuard no_grad;
    layers.back()->weight.zero_();
    layers.back()->bias.zero_();
    layers.back()->bias.narrow(0, act, act).fill_(log_std_init);
  }
  torch::Tensor forward(torch::Tensor x) {
    for (size_t i = 0; i < layers.size(); ++i) {
      x = layers[i]->forward(x);
      if (i + 1 == layers.size()) break;
      if (activation == Activation::kTanh)
        x = torch::tanh(x);
      else if (activation == Activation::kElu)
        x = torch::elu(x);  // alpha 1, as the workers' kElu
      else
        x = torch::relu(x);
    }
    return x;
  }
  std::vector<torch::nn::Linear> layers;
  Activation activation;
};
TORCH_MODULE(Actor);

// Both critics in one module, evaluated together as batched products over a leading critic
// dimension of 2. Per layer: weight [2, in, out] and bias [2, 1, out], uniform in +-1/sqrt(fan_in)
// as torch's nn.Linear (FastSAC's critics); each hidden layer then, where layer_norm, a layer
// normalization over its outputs with its own scale (1) and shift (0) [2, 1, out], and SiLU
// (FastSAC's DistributionalQNetwork). Output: logits [2, B, num_atoms].
struct TwinCriticImpl : torch::nn::Module {
  TwinCriticImpl(int in, const std::vector<int>& hidden, int atoms, bool layer_norm) {
    torch::NoGradGuard no_grad;
    int64_t fan_in = in;
    for (size_t i = 0; i <= hidden.size(); ++i) {
      const int64_t out = i < hidden.size() ? hidden[i] : atoms;
      const std::string k = std::to_string(i);
      const double bound = 1.0 / std::sqrt(double(fan_in));
      w.push_back(register_parameter("w" + k, torch::empty({2, fan_in, out}).uniform_(-bound, bound)));
      b.push_back(register_parameter("b" + k, torch::empty({2, 1, out}).uniform_(-bound, bound)));
      if (layer_norm && i < hidden.size()) {
        scale.push_back(register_parameter("g" + k, torch::ones({2, 1, out})));
        shift.push_back(register_parameter("s" + k, torch::zeros({2, 1, out})));
      }
      fan_in = out;
    }
  }
  torch::Tensor forward(const torch::Tensor& obs, const torch::Tensor& act) {
    const auto sa = torch::cat({obs, act}, 1);
    torch::Tensor x = sa.unsqueeze(0).expand({2, sa.size(0), sa.size(1)});
    for (size_t i = 0; i < w.size(); ++i) {
      x = torch::baddbmm(b[i], x, w[i]);
      if (i + 1 == w.size()) break;
      if (!scale.empty()) x = torch::addcmul(shift[i], torch::layer_norm(x, {x.size(2)}), scale[i]);
      x = torch::silu(x);
    }
    return x;
  }
  std::vector<torch::Tensor> w, b, scale, shift;
};
TORCH_MODULE(TwinCritic);

const config::FastSacConfig& checked(const config::FastSacConfig& cfg, uint64_t seed) {
  check_config(cfg);  // the loader's checks, for a config built in code
  torch::manual_seed(seed);
  return cfg;
}

torch::optim::AdamWOptions adamw(const config::FastSacConfig& c, double lr, double weight_decay) {
  return torch::optim::AdamWOptions(lr)
      .betas(std::make_tuple(c.adam_beta1(), c.adam_beta2()))
      .weight_decay(weight_decay);
}

}  // namespace

torch::Tensor fastsac_critic_target(const torch::Tensor& next_probs1, const torch::Tensor& next_probs2,
                                    const torch::Tensor& rewards, const torch::Tensor& discount,
                                    const torch::Tensor& next_log_prob, const torch::Tensor& alpha, double v_min,
                                    double v_max, bool clipped_double_q) {
  // r + discount * (z - alpha * log_prob) is the projection of z shifted by the soft reward.
  const auto soft_rewards = rewards - discount * alpha * next_log_prob;
  return td3_critic_target(next_probs1, next_probs2, soft_rewards, discount, v_min, v_max, clipped_double_q);
}

torch::Tensor fastsac_temperature_loss(const torch::Tensor& log_alpha, const torch::Tensor& log_prob,
                                       double target_entropy) {
  return -(log_alpha.exp() * (log_prob + target_entropy).detach()).mean();
}

torch::Tensor fastsac_actor_loss(const torch::Tensor& q, const torch::Tensor& log_prob, const torch::Tensor& alpha,
                                 bool clipped_double_q) {
  const auto value = clipped_double_q ? torch::min(q[0], q[1]) : q.mean(0);
  return (alpha.detach() * log_prob - value).mean();
}

struct FastSac::Impl {
  Impl(const config::FastSacConfig& c, int obs, int act)
      : cfg(c),
        obs_dim(obs),
        act_dim(act),
        hidden(fastsac_hidden(c)),
        critic_hidden(fastsac_critic_hidden(c)),
        target_entropy(-double(act) * c.target_entropy_ratio()),
        device(learner_device(c.device(), "fastsac.device")),
        actor(obs, hidden, act, activation_from_name(c.activation()), 0.5 * (c.log_std_min() + c.log_std_max())),
        critic(obs + act, critic_hidden, c.num_atoms(), c.critic_layer_norm()),
        critic_target(obs + act, critic_hidden, c.num_atoms(), c.critic_layer_norm()),
        actor_p(*placed(actor, device)),
        critic_p(*placed(critic, device)),
        target_p(*placed(critic_target, device)),
        support(c51_support(c.num_atoms(), c.v_min(), c.v_max(), torch::TensorOptions().device(device))),
        log_alpha(torch::full({1}, std::log(c.initial_alpha()), torch::TensorOptions().device(device))),
        normalizer(obs),
        last_actor_loss(torch::zeros({}, torch::TensorOptions().device(device))) {
    {
      torch::NoGradGuard no_grad;
      target_p.flat.copy_(critic_p.flat);
      for (auto& t : target_p.params) t.requires_grad_(false);
    }
    log_alpha.requires_grad_(true);
    actor_opt = std::make_unique<torch::optim::AdamW>(std::vector<torch::Tensor>{actor_p.flat},
                                                      adamw(c, c.actor_lr(), c.weight_decay()));
    critic_opt = std::make_unique<torch::optim::AdamW>(std::vector<torch::Tensor>{critic_p.flat},
                                                       adamw(c, c.critic_lr(), c.weight_decay()));
    alpha_opt = std::make_unique<torch::optim::AdamW>(std::vector<torch::Tensor>{log_alpha},
                                                      adamw(c, c.alpha_lr(), c.alpha_weight_decay()));
  }

  // Raw observations [B, obs_dim] on the device, normalized as the workers normalize them.
  torch::Tensor normalized(const torch::Tensor& obs) const { return normalized_obs(obs, moments(), device); }
  const ObsNormalizer* moments() const { return cfg.normalize_observations() ? &normalizer : nullptr; }

  // A reparameterized sample of the actor at normalized obs, as the workers draw it: tanh(mean +
  // exp(log_std) * eps), log_std clamped to its bounds; and its log-probability [B].
  std::pair<torch::Tensor, torch::Tensor> sample(const torch::Tensor& obs) {
    const auto out = actor->forward(obs);
    const auto mean = out.narrow(1, 0, act_dim);
    const auto log_std = out.narrow(1, act_dim, act_dim).clamp(cfg.log_std_min(), cfg.log_std_max());
    const auto pre_tanh = torch::addcmul(mean, torch::exp(log_std), torch::randn_like(mean));
    return {torch::tanh(pre_tanh), squashed_gaussian_log_prob(mean, log_std, pre_tanh)};
  }

  void apply_learning_rates() {
    for (auto [opt, lr, wd] : {std::tuple{actor_opt.get(), cfg.actor_lr(), cfg.weight_decay()},
                               std::tuple{critic_opt.get(), cfg.critic_lr(), cfg.weight_decay()},
                               std::tuple{alpha_opt.get(), cfg.alpha_lr(), cfg.alpha_weight_decay()}})
      for (auto& group : opt->param_groups())
        static_cast<torch::optim::AdamWOptions&>(group.options()) = adamw(cfg, lr, wd);
  }

  config::FastSacConfig cfg;
  int obs_dim, act_dim;
  std::vector<int> hidden, critic_hidden;
  double target_entropy;
  torch::Device device;
  Actor actor;
  TwinCritic critic, critic_target;
  FlatParams actor_p, critic_p, target_p;
  torch::Tensor support, log_alpha;
  ObsNormalizer normalizer;
  torch::Tensor last_actor_loss;  // the figure reported between the actor's steps
  std::unique_ptr<torch::optim::AdamW> actor_opt, critic_opt, alpha_opt;
  int64_t updates = 0;
};

FastSac::FastSac(const config::FastSacConfig& cfg, int obs_dim, int act_dim, uint64_t seed)
    : impl_(std::make_unique<Impl>(checked(cfg, seed), obs_dim, act_dim)) {}
FastSac::~FastSac() = default;
FastSac::FastSac(FastSac&&) noexcept = default;
FastSac& FastSac::operator=(FastSac&&) noexcept = default;

void FastSac::observe(const float* obs, int64_t rows) {
  if (impl_->cfg.normalize_observations()) impl_->normalizer.update(obs, rows);
}

FastSacStats FastSac::update(const SampledBatch& sampled) {
  Impl& s = *impl_;
  const config::FastSacConfig& c = s.cfg;
  // Multi-step rows (fastsac.n_step) bootstrap with gamma^h.
  const auto& [obs, next_obs, actions, rewards, discount] = device_minibatch(sampled, c.gamma(), s.device, s.moments());
  const auto alpha = s.log_alpha.detach().exp();  // the temperature of this update's target

  torch::Tensor target, next_log_prob;
  {
    torch::NoGradGuard no_grad;
    torch::Tensor next_action;
    std::tie(next_action, next_log_prob) = s.sample(next_obs);
    const auto next_probs = torch::softmax(s.critic_target->forward(next_obs, next_action), -1);
    target = fastsac_critic_target(next_probs[0], next_probs[1], rewards, discount, next_log_prob, alpha, c.v_min(),
                                   c.v_max(), c.clipped_double_q());
  }
  const auto logits = s.critic->forward(obs, actions);
  const auto critic_loss = c51_cross_entropy(target, logits);
  step_flat(*s.critic_opt, s.critic_p, critic_loss, c.max_grad_norm());

  // FastSAC's temperature step follows the critics', on the next actions' log-probabilities.
  torch::Tensor alpha_loss = torch::zeros({}, torch::TensorOptions().device(s.device));
  if (c.autotune()) {
    alpha_loss = fastsac_temperature_loss(s.log_alpha, next_log_prob, s.target_entropy);
    s.log_alpha.mutable_grad() = torch::autograd::grad({alpha_loss}, {s.log_alpha})[0];
    s.alpha_opt->step();
  }

  FastSacStats st;
  // FastSAC steps the actor at the updates i % policy_frequency == 1 (every update for 1), after
  // the critics' and the temperature's steps, against the critics just stepped.
  const int d = c.policy_delay();
  st.actor_stepped = s.updates % d == (d > 1 ? 1 : 0);
  if (st.actor_stepped) {
    const auto [action, log_prob] = s.sample(obs);
    const auto q = c51_expected_value(torch::softmax(s.critic->forward(obs, action), -1), s.support);
    const auto actor_loss = fastsac_actor_loss(q, log_prob, s.log_alpha.detach().exp(), c.clipped_double_q());
    step_flat(*s.actor_opt, s.actor_p, actor_loss, c.max_grad_norm());
    s.last_actor_loss = actor_loss.detach();
  }
  {
    torch::NoGradGuard no_grad;
    s.target_p.flat.lerp_(s.critic_p.flat, c.tau());
    const auto q_mean = c51_expected_value(torch::softmax(logits.detach(), -1), s.support).mean();
    // One read-back for the figures: on a GPU each item() is a synchronization.
    const auto figures =
        torch::stack({critic_loss.detach().reshape({}), s.last_actor_loss.reshape({}), alpha.reshape({}),
                      alpha_loss.detach().reshape({}), -next_log_prob.mean(), q_mean})
            .to(torch::kCPU, torch::kDouble);
    const double* f = figures.data_ptr<double>();
    st.critic_loss = f[0];
    st.actor_loss = f[1];
    st.alpha = f[2];
    st.alpha_loss = f[3];
    st.entropy = f[4];
    st.q_mean = f[5];
  }
  ++s.updates;
  return st;
}

PolicyParams FastSac::export_policy(uint64_t version) const {
  const Impl& s = *impl_;
  PolicyParams p = fastsac_policy_shape(s.cfg, s.obs_dim, s.act_dim);
  p.version = version;
  torch::NoGradGuard no_grad;
  std::vector<torch::Tensor> flat;
  for (const auto& layer : s.actor->layers) {
    flat.push_back(layer->weight.detach().to(torch::kCPU).reshape(-1));
    flat.push_back(layer->bias.detach().to(torch::kCPU).reshape(-1));
  }
  const auto all = torch::cat(flat).contiguous();
  p.params.assign(all.data_ptr<float>(), all.data_ptr<float>() + all.numel());
  if (s.cfg.normalize_observations()) {
    p.obs_mean = s.normalizer.mean();
    p.obs_std = s.normalizer.std();
  }
  return p;
}

int64_t FastSac::updates() const { return impl_->updates; }
bool FastSac::on_gpu() const { return impl_->device.is_cuda(); }
torch::Device FastSac::device() const { return impl_->device; }
int FastSac::obs_dim() const { return impl_->obs_dim; }
int FastSac::act_dim() const { return impl_->act_dim; }
const std::vector<int>& FastSac::hidden() const { return impl_->hidden; }
const std::vector<int>& FastSac::critic_hidden() const { return impl_->critic_hidden; }
torch::Tensor FastSac::support() const { return impl_->support; }
double FastSac::alpha() const { return impl_->log_alpha.detach().exp().item<double>(); }
double FastSac::target_entropy() const { return impl_->target_entropy; }

torch::Tensor FastSac::actor_output(const torch::Tensor& obs) const {
  torch::NoGradGuard no_grad;
  return impl_->actor->forward(impl_->normalized(obs.to(impl_->device))).to(obs.device());
}

torch::Tensor FastSac::deterministic_action(const torch::Tensor& obs) const {
  return torch::tanh(actor_output(obs).narrow(1, 0, impl_->act_dim));
}

torch::Tensor FastSac::critic_logits(const torch::Tensor& obs, const torch::Tensor& actions) const {
  torch::NoGradGuard no_grad;
  Impl& s = *impl_;
  return s.critic->forward(s.normalized(obs.to(s.device)), actions.to(s.device)).to(obs.device());
}

std::vector<torch::Tensor> FastSac::actor_parameters() const { return impl_->actor_p.params; }
std::vector<torch::Tensor> FastSac::critic_parameters() const { return impl_->critic_p.params; }
std::vector<torch::Tensor> FastSac::target_critic_parameters() const { return impl_->target_p.params; }

namespace {
C51Record record_of(const FastSac& f, const config::FastSacConfig& c) {
  return {f.obs_dim(), f.act_dim(), c.num_atoms(), f.hidden(), f.critic_hidden(), c.v_min(), c.v_max()};
}
}  // namespace

void FastSac::save(const std::string& dir) const {
  const Impl& s = *impl_;
  std::filesystem::create_directories(dir);
  const std::string file = dir + "/fastsac.pt", tmp = file + ".tmp";
  try {
    torch::serialize::OutputArchive root;
    write_c51_record(root, record_of(*this, s.cfg));
    write_params(root, "actor", *s.actor);
    write_params(root, "critic", *s.critic);
    write_params(root, "critic_target", *s.critic_target);
    root.write("log_alpha", s.log_alpha.detach().to(torch::kCPU));
    for (const auto& [key, opt] : {std::pair<const char*, torch::optim::Optimizer*>{"actor_optim", s.actor_opt.get()},
                                   {"critic_optim", s.critic_opt.get()},
                                   {"alpha_optim", s.alpha_opt.get()}}) {
      torch::serialize::OutputArchive a;
      opt->save(a);
      root.write(key, a);
    }
    write_moments(root, s.normalizer);
    root.write("last_actor_loss", s.last_actor_loss.detach().to(torch::kCPU));
    root.write("updates", torch::full({1}, s.updates, torch::kInt64));
    save_archive(root, tmp);
  } catch (const c10::Error& e) {
    throw std::runtime_error("fastsac checkpoint " + tmp + ": " + e.what_without_backtrace());
  }
  if (std::rename(tmp.c_str(), file.c_str()) != 0)
    throw std::runtime_error("fastsac checkpoint " + file + ": cannot rename " + tmp + " to it");
}

void FastSac::load(const std::string& dir) {
  Impl& s = *impl_;
  const std::string file = dir + "/fastsac.pt", what = "fastsac checkpoint";
  auto fail = [&](const std::string& why) { return std::runtime_error(what + " " + file + ": " + why); };
  try {
    torch::serialize::InputArchive root;
    root.load_from(file, s.device);
    check_c51_record(root, record_of(*this, s.cfg), "fastsac", file);
    const auto actor = read_params(root, "actor", *s.actor, what, file);
    const auto critic = read_params(root, "critic", *s.critic, what, file);
    const auto target = read_params(root, "critic_target", *s.critic_target, what, file);
    torch::Tensor log_alpha, actor_loss, updates;
    if (!root.try_read("log_alpha", log_alpha) || log_alpha.numel() != 1)
      throw fail("missing or misshapen 'log_alpha'");
    ObsNormalizer moments(s.obs_dim);  // read aside: nothing changes before every entry fits
    if (!read_moments(root, moments)) throw fail("missing or misshapen observation moments");
    if (!root.try_read("last_actor_loss", actor_loss) || actor_loss.numel() != 1)
      throw fail("missing or misshapen 'last_actor_loss'");
    if (!root.try_read("updates", updates) || updates.numel() != 1) throw fail("missing or misshapen 'updates'");
    torch::serialize::InputArchive actor_opt, critic_opt, alpha_opt;
    if (!root.try_read("actor_optim", actor_opt) || !root.try_read("critic_optim", critic_opt) ||
        !root.try_read("alpha_optim", alpha_opt))
      throw fail("missing optimizer state");

    copy_into(s.actor_p.params, actor);
    copy_into(s.critic_p.params, critic);
    copy_into(s.target_p.params, target);
    copy_into({s.log_alpha}, {log_alpha.reshape({1})});
    s.actor_opt->load(actor_opt);
    s.critic_opt->load(critic_opt);
    s.alpha_opt->load(alpha_opt);
    s.normalizer = moments;
    s.last_actor_loss = actor_loss.reshape({}).to(s.device, torch::kFloat);
    s.updates = updates.to(torch::kCPU).item<int64_t>();
    // The saved optimizers carry the settings they ran with; this run's are its config's.
    s.apply_learning_rates();
  } catch (const c10::Error& e) {
    throw fail(e.what_without_backtrace());
  }
}

}  // namespace farm
