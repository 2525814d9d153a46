#include "td3.h"

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <stdexcept>
#include <utility>

#include "archive_io.h"
#include "compute.h"
#include "config.h"
#include "device_minibatch.h"
#include "flat_params.h"
#include "obs_normalizer.h"
#include "policy_shape.h"

namespace farm {

namespace {

std::vector<int64_t> layer_sizes(int in, const std::vector<int>& hidden, int out) {
  std::vector<int64_t> s{in};
  s.insert(s.end(), hidden.begin(), hidden.end());
  s.push_back(out);
  return s;
}

// The deterministic actor: Linear layers with ReLU between them and tanh on the output, so that
// weight.flatten() then bias of each layer is the workers' flat layout. The hidden layers keep
// torch::nn::Linear's default initialization (PyTorch's, as FastTD3's nn.Linear); the output layer
// starts at N(0, init_scale) weights and zero bias (FastTD3 init_scale).
struct ActorImpl : torch::nn::Module {
  ActorImpl(const std::vector<int64_t>& sizes, double init_scale) {
    for (size_t i = 0; i + 1 < sizes.size(); ++i)
      layers.push_back(register_module("l" + std::to_string(i), torch::nn::Linear(sizes[i], sizes[i + 1])));
    torch::NoGradGuard no_grad;
    layers.back()->weight.normal_(0.0, init_scale);
    layers.back()->bias.zero_();
  }
  torch::Tensor forward(torch::Tensor x) {
    for (size_t i = 0; i < layers.size(); ++i) {
      x = layers[i]->forward(x);
      if (i + 1 < layers.size()) x.relu_();
    }
    return torch::tanh(x);
  }
  std::vector<torch::nn::Linear> layers;
};
TORCH_MODULE(Actor);

// Both critics in one module, evaluated together as batched products over a leading critic
// dimension of 2; weights [critic, in, out], biases [critic, 1, out], each initialized uniform in
// +-1/sqrt(fan_in) as torch's nn.Linear (FastTD3's critics). Output: logits [2, B, num_atoms].
struct TwinCriticImpl : torch::nn::Module {
  explicit TwinCriticImpl(const std::vector<int64_t>& sizes) {
    torch::NoGradGuard no_grad;
    for (size_t i = 0; i + 1 < sizes.size(); ++i) {
      const std::string k = std::to_string(i);
      const double bound = 1.0 / std::sqrt(double(sizes[i]));
      w.push_back(register_parameter("w" + k, torch::empty({2, sizes[i], sizes[i + 1]}).uniform_(-bound, bound)));
      b.push_back(register_parameter("b" + k, torch::empty({2, 1, sizes[i + 1]}).uniform_(-bound, bound)));
    }
  }
  torch::Tensor forward(const torch::Tensor& obs, const torch::Tensor& act) {
    const auto sa = torch::cat({obs, act}, 1);
    torch::Tensor x = sa.unsqueeze(0).expand({2, sa.size(0), sa.size(1)});
    for (size_t i = 0; i < w.size(); ++i) {
      x = torch::baddbmm(b[i], x, w[i]);
      if (i + 1 < w.size()) x.relu_();
    }
    return x;
  }
  std::vector<torch::Tensor> w, b;
};
TORCH_MODULE(TwinCritic);

const config::Td3Config& checked(const config::Td3Config& cfg, uint64_t seed) {
  check_config(cfg);  // the loader's checks, for a config built in code
  torch::manual_seed(seed);
  return cfg;
}

}  // namespace

torch::Tensor c51_support(int num_atoms, double v_min, double v_max, const torch::TensorOptions& options) {
  return torch::linspace(v_min, v_max, num_atoms, options);
}

torch::Tensor c51_projection(const torch::Tensor& probs, const torch::Tensor& rewards, const torch::Tensor& discount,
                             double v_min, double v_max) {
  const int64_t k = probs.size(-1);
  const double dz = (v_max - v_min) / double(k - 1);
  const auto z = c51_support(int(k), v_min, v_max, probs.options());
  const auto shifted = torch::addcmul(rewards.unsqueeze(-1), discount.unsqueeze(-1), z).clamp_(v_min, v_max);
  const auto b = ((shifted - v_min) / dz).clamp_(0.0, double(k - 1));  // the atom's fractional index
  const auto lower = b.floor(), upper = b.ceil();
  // On an atom (lower == upper) the lower neighbour takes it all; otherwise the split is linear.
  const auto to_lower = (upper - b).add_(lower.eq(upper).to(b.scalar_type()));
  const auto to_upper = b - lower;
  auto out = torch::zeros_like(probs);
  out.scatter_add_(-1, lower.to(torch::kLong), probs * to_lower);
  out.scatter_add_(-1, upper.to(torch::kLong), probs * to_upper);
  return out;
}

torch::Tensor c51_expected_value(const torch::Tensor& probs, const torch::Tensor& support) {
  return (probs * support).sum(-1);
}

torch::Tensor td3_critic_target(const torch::Tensor& next_probs1, const torch::Tensor& next_probs2,
                                const torch::Tensor& rewards, const torch::Tensor& discount, double v_min, double v_max,
                                bool clipped_double_q) {
  const auto p1 = c51_projection(next_probs1, rewards, discount, v_min, v_max);
  const auto p2 = c51_projection(next_probs2, rewards, discount, v_min, v_max);
  if (!clipped_double_q) return torch::stack({p1, p2});
  const auto z = c51_support(int(p1.size(-1)), v_min, v_max, p1.options());
  const auto first_smaller = c51_expected_value(p1, z).lt(c51_expected_value(p2, z)).unsqueeze(-1);
  const auto picked = torch::where(first_smaller, p1, p2);
  return torch::stack({picked, picked});
}

torch::Tensor c51_cross_entropy(const torch::Tensor& target, const torch::Tensor& logits) {
  return -(target * torch::log_softmax(logits, -1)).sum(-1).mean(-1).sum();
}

struct Td3::Impl {
  Impl(const config::Td3Config& c, int obs, int act)
      : cfg(c),
        obs_dim(obs),
        act_dim(act),
        hidden(td3_hidden(c)),
        critic_hidden(td3_critic_hidden(c)),
        device(learner_device(c.device(), "td3.device")),
        actor(layer_sizes(obs, hidden, act), c.init_scale()),
        critic(layer_sizes(obs + act, critic_hidden, c.num_atoms())),
        critic_target(layer_sizes(obs + act, critic_hidden, c.num_atoms())),
        actor_p(*placed(actor, device)),
        critic_p(*placed(critic, device)),
        target_p(*placed(critic_target, device)),
        support(c51_support(c.num_atoms(), c.v_min(), c.v_max(), torch::TensorOptions().device(device))),
        normalizer(obs),
        last_actor_loss(torch::zeros({}, torch::TensorOptions().device(device))) {
    {
      torch::NoGradGuard no_grad;
      target_p.flat.copy_(critic_p.flat);
      for (auto& t : target_p.params) t.requires_grad_(false);
    }
    actor_opt =
        std::make_unique<torch::optim::AdamW>(std::vector<torch::Tensor>{actor_p.flat},
                                              torch::optim::AdamWOptions(c.actor_lr()).weight_decay(c.weight_decay()));
    critic_opt =
        std::make_unique<torch::optim::AdamW>(std::vector<torch::Tensor>{critic_p.flat},
                                              torch::optim::AdamWOptions(c.critic_lr()).weight_decay(c.weight_decay()));
  }

  // Raw observations [B, obs_dim] on the device, normalized as the workers normalize them.
  torch::Tensor normalized(const torch::Tensor& obs) const { return normalized_obs(obs, moments(), device); }
  const ObsNormalizer* moments() const { return cfg.normalize_observations() ? &normalizer : nullptr; }

  void apply_learning_rates() {
    for (auto [opt, lr] : {std::pair{actor_opt.get(), cfg.actor_lr()}, std::pair{critic_opt.get(), cfg.critic_lr()}})
      for (auto& group : opt->param_groups())
        static_cast<torch::optim::AdamWOptions&>(group.options()).lr(lr).weight_decay(cfg.weight_decay());
  }

  config::Td3Config cfg;
  int obs_dim, act_dim;
  std::vector<int> hidden, critic_hidden;
  torch::Device device;
  Actor actor;
  TwinCritic critic, critic_target;
  FlatParams actor_p, critic_p, target_p;
  torch::Tensor support;
  ObsNormalizer normalizer;
  torch::Tensor last_actor_loss;  // the figure reported between the actor's steps
  std::unique_ptr<torch::optim::AdamW> actor_opt, critic_opt;
  int64_t updates = 0;
};

Td3::Td3(const config::Td3Config& cfg, int obs_dim, int act_dim, uint64_t seed)
    : impl_(std::make_unique<Impl>(checked(cfg, seed), obs_dim, act_dim)) {}
Td3::~Td3() = default;
Td3::Td3(Td3&&) noexcept = default;
Td3& Td3::operator=(Td3&&) noexcept = default;

void Td3::observe(const float* obs, int64_t rows) {
  if (impl_->cfg.normalize_observations()) impl_->normalizer.update(obs, rows);
}

Td3Stats Td3::update(const SampledBatch& sampled) {
  Impl& s = *impl_;
  const config::Td3Config& c = s.cfg;
  // Multi-step rows (td3.n_step) bootstrap with gamma^h.
  const auto& [obs, next_obs, actions, rewards, discount] = device_minibatch(sampled, c.gamma(), s.device, s.moments());

  torch::Tensor target;
  {
    torch::NoGradGuard no_grad;
    // Target policy smoothing, from the online actor (FastTD3 keeps no target actor).
    const auto noise = (torch::randn_like(actions) * c.policy_noise()).clamp_(-c.noise_clip(), c.noise_clip());
    const auto next_action = (s.actor->forward(next_obs) + noise).clamp_(-1.0, 1.0);
    const auto next_probs = torch::softmax(s.critic_target->forward(next_obs, next_action), -1);
    target =
        td3_critic_target(next_probs[0], next_probs[1], rewards, discount, c.v_min(), c.v_max(), c.clipped_double_q());
  }
  const auto logits = s.critic->forward(obs, actions);
  const auto critic_loss = c51_cross_entropy(target, logits);
  step_flat(*s.critic_opt, s.critic_p, critic_loss, c.max_grad_norm());

  Td3Stats st;
  // FastTD3's order: the actor's step after the critics', against the critics just stepped.
  st.actor_stepped = s.updates % c.policy_delay() == c.policy_delay() - 1;
  if (st.actor_stepped) {
    const auto q = c51_expected_value(torch::softmax(s.critic->forward(obs, s.actor->forward(obs)), -1), s.support);
    const auto value = c.clipped_double_q() ? torch::min(q[0], q[1]) : q.mean(0);
    const auto actor_loss = -value.mean();
    step_flat(*s.actor_opt, s.actor_p, actor_loss, c.max_grad_norm());
    s.last_actor_loss = actor_loss.detach();
  }
  {
    torch::NoGradGuard no_grad;
    s.target_p.flat.lerp_(s.critic_p.flat, c.tau());
    const auto q_mean = c51_expected_value(torch::softmax(logits.detach(), -1), s.support).mean();
    // One read-back for the figures: on a GPU each item() is a synchronization.
    const auto figures = torch::stack({critic_loss.detach().reshape({}), s.last_actor_loss.reshape({}), q_mean})
                             .to(torch::kCPU, torch::kDouble);
    const double* f = figures.data_ptr<double>();
    st.critic_loss = f[0];
    st.actor_loss = f[1];
    st.q_mean = f[2];
  }
  ++s.updates;
  return st;
}

double Td3::exploration_std() const { return 0.5 * (impl_->cfg.std_min() + impl_->cfg.std_max()); }

PolicyParams Td3::export_policy(uint64_t version) const {
  const Impl& s = *impl_;
  PolicyParams p = td3_policy_shape(s.cfg, s.obs_dim, s.act_dim);
  p.version = version;
  torch::NoGradGuard no_grad;
  std::vector<torch::Tensor> flat;
  for (size_t i = 0; i < s.actor->layers.size(); ++i) {
    torch::Tensor w = s.actor->layers[i]->weight.detach().to(torch::kCPU);
    torch::Tensor b = s.actor->layers[i]->bias.detach().to(torch::kCPU);
    if (i + 1 == s.actor->layers.size()) {
      // The head's log-std rows: zero weights, the exploration std's log as bias.
      w = torch::cat({w, torch::zeros_like(w)}, 0);
      b = torch::cat({b, torch::full_like(b, std::log(exploration_std()))}, 0);
    }
    flat.push_back(w.reshape(-1));
    flat.push_back(b.reshape(-1));
  }
  const auto all = torch::cat(flat).contiguous();
  p.params.assign(all.data_ptr<float>(), all.data_ptr<float>() + all.numel());
  if (s.cfg.normalize_observations()) {
    p.obs_mean = s.normalizer.mean();
    p.obs_std = s.normalizer.std();
  }
  return p;
}

int64_t Td3::updates() const { return impl_->updates; }
bool Td3::on_gpu() const { return impl_->device.is_cuda(); }
torch::Device Td3::device() const { return impl_->device; }
int Td3::obs_dim() const { return impl_->obs_dim; }
int Td3::act_dim() const { return impl_->act_dim; }
const std::vector<int>& Td3::hidden() const { return impl_->hidden; }
const std::vector<int>& Td3::critic_hidden() const { return impl_->critic_hidden; }
torch::Tensor Td3::support() const { return impl_->support; }

torch::Tensor Td3::deterministic_action(const torch::Tensor& obs) const {
  torch::NoGradGuard no_grad;
  return impl_->actor->forward(impl_->normalized(obs.to(impl_->device))).to(obs.device());
}

torch::Tensor Td3::critic_logits(const torch::Tensor& obs, const torch::Tensor& actions) const {
  torch::NoGradGuard no_grad;
  Impl& s = *impl_;
  return s.critic->forward(s.normalized(obs.to(s.device)), actions.to(s.device)).to(obs.device());
}

std::vector<torch::Tensor> Td3::actor_parameters() const { return impl_->actor_p.params; }
std::vector<torch::Tensor> Td3::critic_parameters() const { return impl_->critic_p.params; }
std::vector<torch::Tensor> Td3::target_critic_parameters() const { return impl_->target_p.params; }

namespace {
std::vector<int64_t> c51_meta(const C51Record& r) {
  std::vector<int64_t> m{r.obs_dim, r.act_dim, r.num_atoms};
  m.insert(m.end(), r.hidden.begin(), r.hidden.end());
  m.push_back(-1);
  m.insert(m.end(), r.critic_hidden.begin(), r.critic_hidden.end());
  return m;
}
}  // namespace

void write_c51_record(torch::serialize::OutputArchive& root, const C51Record& r) {
  root.write("meta", torch::tensor(c51_meta(r), torch::kInt64));
  root.write("support", doubles({r.v_min, r.v_max}));
}

void check_c51_record(torch::serialize::InputArchive& root, const C51Record& r, const std::string& section,
                      const std::string& file) {
  auto fail = [&](const std::string& what) {
    return std::runtime_error(section + " checkpoint " + file + ": " + what);
  };
  const std::vector<int64_t> want = c51_meta(r);
  torch::Tensor meta, support;
  if (!root.try_read("meta", meta)) throw fail("no 'meta'");
  meta = meta.to(torch::kCPU).contiguous();
  const std::vector<int64_t> got(meta.data_ptr<int64_t>(), meta.data_ptr<int64_t>() + meta.numel());
  if (got != want)
    throw fail("networks are obs,act,atoms,actor hidden,-1,critic hidden = " + sizes_str(got) + ", expected " +
               sizes_str(want));
  if (!root.try_read("support", support) || support.numel() != 2) throw fail("missing or misshapen 'support'");
  const auto vs = to_doubles(support);
  if (vs[0] != r.v_min || vs[1] != r.v_max)
    throw fail("its critics' support is [" + std::to_string(vs[0]) + ", " + std::to_string(vs[1]) +
               "], this config's " + section + ".v_min, " + section + ".v_max [" + std::to_string(r.v_min) + ", " +
               std::to_string(r.v_max) + "]");
}

namespace {
C51Record record_of(const Td3& t, const config::Td3Config& c) {
  return {t.obs_dim(), t.act_dim(), c.num_atoms(), t.hidden(), t.critic_hidden(), c.v_min(), c.v_max()};
}
}  // namespace

void Td3::save(const std::string& dir) const {
  const Impl& s = *impl_;
  std::filesystem::create_directories(dir);
  const std::string file = dir + "/td3.pt", tmp = file + ".tmp";
  try {
    torch::serialize::OutputArchive root;
    write_c51_record(root, record_of(*this, s.cfg));
    write_params(root, "actor", *s.actor);
    write_params(root, "critic", *s.critic);
    write_params(root, "critic_target", *s.critic_target);
    for (const auto& [key, opt] : {std::pair<const char*, torch::optim::Optimizer*>{"actor_optim", s.actor_opt.get()},
                                   {"critic_optim", s.critic_opt.get()}}) {
      torch::serialize::OutputArchive a;
      opt->save(a);
      root.write(key, a);
    }
    write_moments(root, s.normalizer);
    root.write("last_actor_loss", s.last_actor_loss.detach().to(torch::kCPU));
    root.write("updates", torch::full({1}, s.updates, torch::kInt64));
    save_archive(root, tmp);
  } catch (const c10::Error& e) {
    throw std::runtime_error("td3 checkpoint " + tmp + ": " + e.what_without_backtrace());
  }
  if (std::rename(tmp.c_str(), file.c_str()) != 0)
    throw std::runtime_error("td3 checkpoint " + file + ": cannot rename " + tmp + " to it");
}

void Td3::load(const std::string& dir) {
  Impl& s = *impl_;
  const std::string file = dir + "/td3.pt";
  auto fail = [&](const std::string& what) { return std::runtime_error("td3 checkpoint " + file + ": " + what); };
  try {
    torch::serialize::InputArchive root;
    root.load_from(file, s.device);
    check_c51_record(root, record_of(*this, s.cfg), "td3", file);
    const auto actor = read_params(root, "actor", *s.actor, "td3 checkpoint", file);
    const auto critic = read_params(root, "critic", *s.critic, "td3 checkpoint", file);
    const auto target = read_params(root, "critic_target", *s.critic_target, "td3 checkpoint", file);
    torch::Tensor actor_loss, updates;
    ObsNormalizer moments(s.obs_dim);  // read aside: nothing changes before every entry fits
    if (!read_moments(root, moments)) throw fail("missing or misshapen observation moments");
    if (!root.try_read("last_actor_loss", actor_loss) || actor_loss.numel() != 1)
      throw fail("missing or misshapen 'last_actor_loss'");
    if (!root.try_read("updates", updates) || updates.numel() != 1) throw fail("missing or misshapen 'updates'");
    torch::serialize::InputArchive actor_opt, critic_opt;
    if (!root.try_read("actor_optim", actor_opt) || !root.try_read("critic_optim", critic_opt))
      throw fail("missing optimizer state");

    copy_into(s.actor_p.params, actor);
    copy_into(s.critic_p.params, critic);
    copy_into(s.target_p.params, target);
    s.actor_opt->load(actor_opt);
    s.critic_opt->load(critic_opt);
    s.normalizer = moments;
    s.last_actor_loss = actor_loss.reshape({}).to(s.device, torch::kFloat);
    s.updates = updates.to(torch::kCPU).item<int64_t>();
    // The saved optimizers carry the rates they ran with; this run's are its config's.
    s.apply_learning_rates();
  } catch (const c10::Error& e) {
    throw fail(e.what_without_backtrace());
  }
}

}  // namespace farm
