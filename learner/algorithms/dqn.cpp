#include "dqn.h"
#include "archive_io.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <stdexcept>

#include "config.h"

namespace farm {

namespace {

// Plain MLP of torch::nn::Linear layers: weight.flatten() then bias per layer is the flat layout
// the workers' EigenMlp reads.
struct QNetImpl : torch::nn::Module {
  explicit QNetImpl(const std::vector<int64_t>& sizes) {
    for (size_t i = 0; i + 1 < sizes.size(); ++i)
      layers.push_back(register_module("l" + std::to_string(i), torch::nn::Linear(sizes[i], sizes[i + 1])));
  }
  torch::Tensor forward(torch::Tensor x) {
    for (size_t i = 0; i < layers.size(); ++i) {
      x = layers[i]->forward(x);
      if (i + 1 < layers.size()) x = torch::relu(x);
    }
    return x;
  }
  std::vector<torch::nn::Linear> layers;
};
TORCH_MODULE(QNet);

std::vector<int> dqn_hidden(const config::DqnConfig& c) {
  if (c.hidden_size() == 0) return {64, 64};  // sb3 DQN net_arch
  return {c.hidden().begin(), c.hidden().end()};
}

}  // namespace

torch::Tensor dqn_target(const torch::Tensor& reward, const torch::Tensor& terminated,
                         const torch::Tensor& next_q_online, const torch::Tensor& next_q_target, double gamma,
                         bool double_q, const torch::Tensor& horizon) {
  torch::Tensor next_v;
  if (double_q) {
    const auto best = next_q_online.argmax(1, /*keepdim=*/true);
    next_v = next_q_target.gather(1, best).squeeze(1);
  } else {
    next_v = std::get<0>(next_q_target.max(1));
  }
  if (!horizon.defined()) return reward + gamma * (1.0 - terminated) * next_v;
  return reward + torch::pow(gamma, horizon) * (1.0 - terminated) * next_v;
}

double dqn_epsilon(const config::DqnConfig& c, int64_t env_steps) {
  const double span = c.exploration_fraction() * double(c.schedule_env_steps());
  const double progress = span > 0 ? std::min(1.0, double(env_steps) / span) : 1.0;
  return c.exploration_initial_eps() + progress * (c.exploration_final_eps() - c.exploration_initial_eps());
}

struct Dqn::Impl {
  Impl(const config::DqnConfig& c, int obs, int actions)
      : cfg(c), obs_dim(obs), num_actions(actions), hidden(dqn_hidden(c)), online(sizes()), target(sizes()) {
    check_config(c);  // the loader's checks, for a config built in code
    if (obs < 1 || actions < 2) {
      throw std::invalid_argument("dqn: needs obs_dim >= 1 and >= 2 discrete actions, got " + std::to_string(obs) +
                                  " and " + std::to_string(actions));
    }
    copy_target();
    for (auto& p : target->parameters()) p.requires_grad_(false);
    opt = std::make_unique<torch::optim::Adam>(online->parameters(), torch::optim::AdamOptions(cfg.learning_rate()));
  }
  std::vector<int64_t> sizes() const {
    std::vector<int64_t> s{obs_dim};
    s.insert(s.end(), hidden.begin(), hidden.end());
    s.push_back(num_actions);
    return s;
  }
  void copy_target() {
    torch::NoGradGuard no_grad;
    auto src = online->parameters(), dst = target->parameters();
    for (size_t i = 0; i < src.size(); ++i) dst[i].copy_(src[i]);
  }

  config::DqnConfig cfg;
  int obs_dim, num_actions;
  std::vector<int> hidden;
  QNet online, target;
  std::unique_ptr<torch::optim::Adam> opt;
  int64_t updates = 0;
};

static const config::DqnConfig& seeded(const config::DqnConfig& cfg, uint64_t seed) {
  torch::manual_seed(seed);
  return cfg;
}

Dqn::Dqn(const config::DqnConfig& cfg, int obs_dim, int num_actions, uint64_t seed)
    : impl_(std::make_unique<Impl>(seeded(cfg, seed), obs_dim, num_actions)) {}
Dqn::~Dqn() = default;
Dqn::Dqn(Dqn&&) noexcept = default;
Dqn& Dqn::operator=(Dqn&&) noexcept = default;

DqnStats Dqn::update(const SampledBatch& batch) {
  Impl& s = *impl_;
  const auto actions = batch.actions.reshape({-1, 1}).round().to(torch::kLong);
  torch::Tensor target;
  {
    torch::NoGradGuard no_grad;
    const auto next_target = s.target->forward(batch.next_obs);
    const auto next_online = s.cfg.double_q() ? s.online->forward(batch.next_obs) : next_target;
    target = dqn_target(batch.rewards, batch.terminated, next_online, next_target, s.cfg.gamma(), s.cfg.double_q(),
                        batch.horizon);
  }
  const auto q = s.online->forward(batch.obs).gather(1, actions).squeeze(1);
  const auto loss = torch::smooth_l1_loss(q, target);
  s.opt->zero_grad();
  loss.backward();
  torch::nn::utils::clip_grad_norm_(s.online->parameters(), s.cfg.max_grad_norm());
  s.opt->step();
  ++s.updates;
  if (s.updates % s.cfg.target_update_updates() == 0) s.copy_target();
  DqnStats st;
  st.loss = loss.item<double>();
  st.q_mean = q.mean().item<double>();
  st.target_mean = target.mean().item<double>();
  return st;
}

double Dqn::epsilon() const { return dqn_epsilon(impl_->cfg, env_steps_); }

PolicyParams Dqn::export_policy(uint64_t version) const {
  const Impl& s = *impl_;
  PolicyParams p;
  p.version = version;
  p.head = PolicyHead::kDiscreteQ;
  p.layout.activation = Activation::kRelu;
  p.layout.sizes.push_back(s.obs_dim);
  p.layout.sizes.insert(p.layout.sizes.end(), s.hidden.begin(), s.hidden.end());
  p.layout.sizes.push_back(s.num_actions);
  p.epsilon = float(epsilon());
  for (const auto& layer : s.online->layers) {
    const auto w = layer->weight.detach().contiguous();
    const auto b = layer->bias.detach().contiguous();
    p.params.insert(p.params.end(), w.data_ptr<float>(), w.data_ptr<float>() + w.numel());
    p.params.insert(p.params.end(), b.data_ptr<float>(), b.data_ptr<float>() + b.numel());
  }
  return p;
}

int64_t Dqn::updates() const { return impl_->updates; }
int Dqn::obs_dim() const { return impl_->obs_dim; }
int Dqn::num_actions() const { return impl_->num_actions; }
const std::vector<int>& Dqn::hidden() const { return impl_->hidden; }

torch::Tensor Dqn::q_values(const torch::Tensor& obs) const {
  torch::NoGradGuard no_grad;
  return impl_->online->forward(obs);
}

std::vector<torch::Tensor> Dqn::online_parameters() const { return impl_->online->parameters(); }
std::vector<torch::Tensor> Dqn::target_parameters() const { return impl_->target->parameters(); }

void Dqn::save(const std::string& dir) const {
  const Impl& s = *impl_;
  std::filesystem::create_directories(dir);
  const std::string file = dir + "/dqn.pt", tmp = file + ".tmp";
  try {
    torch::serialize::OutputArchive root;
    std::vector<int64_t> meta{s.obs_dim, s.num_actions};
    meta.insert(meta.end(), s.hidden.begin(), s.hidden.end());
    root.write("meta", torch::tensor(meta, torch::kInt64));
    torch::serialize::OutputArchive online, target, optim;
    s.online->save(online);
    s.target->save(target);
    s.opt->save(optim);
    root.write("online", online);
    root.write("target", target);
    root.write("optim", optim);
    root.write("updates", torch::full({1}, s.updates, torch::kInt64));
    root.write("env_steps", torch::full({1}, env_steps_, torch::kInt64));
    save_archive(root, tmp);
  } catch (const c10::Error& e) {
    throw std::runtime_error("dqn checkpoint " + tmp + ": " + e.what_without_backtrace());
  }
  if (std::rename(tmp.c_str(), file.c_str()) != 0)
    throw std::runtime_error("dqn checkpoint " + file + ": cannot rename " + tmp + " to it");
}

void Dqn::load(const std::string& dir) {
  Impl& s = *impl_;
  const std::string file = dir + "/dqn.pt";
  try {
    torch::serialize::InputArchive root;
    root.load_from(file);
    torch::Tensor meta;
    root.read("meta", meta);
    std::vector<int64_t> want{s.obs_dim, s.num_actions};
    want.insert(want.end(), s.hidden.begin(), s.hidden.end());
    const auto m = meta.to(torch::kInt64).contiguous();
    if (std::vector<int64_t>(m.data_ptr<int64_t>(), m.data_ptr<int64_t>() + m.numel()) != want) {
      throw std::runtime_error("dqn checkpoint " + file +
                               ": network sizes (obs, actions, hidden...) differ from this config");
    }
    // Into fresh networks first, so a failed read leaves this instance as it was.
    QNet online(s.sizes()), target(s.sizes());
    torch::serialize::InputArchive a, b, o;
    root.read("online", a);
    root.read("target", b);
    online->load(a);
    target->load(b);
    torch::NoGradGuard no_grad;
    auto copy = [](QNet& from, QNet& to) {
      auto src = from->parameters(), dst = to->parameters();
      for (size_t i = 0; i < src.size(); ++i) dst[i].copy_(src[i]);
    };
    copy(online, s.online);
    copy(target, s.target);
    root.read("optim", o);
    s.opt->load(o);
    torch::Tensor u, e;
    root.read("updates", u);
    root.read("env_steps", e);
    s.updates = u.item<int64_t>();
    env_steps_ = e.item<int64_t>();
  } catch (const c10::Error& e) {
    throw std::runtime_error("dqn checkpoint " + file + ": " + e.what_without_backtrace());
  }
}

}  // namespace farm
