#include "dqn.h"
#include "archive_io.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <stdexcept>

#include "compute.h"
#include "config.h"
#include "device_replay.h"
#include "linear_mlp.h"
#include "policy_shape.h"

#include <ATen/Context.h>

#ifdef FARM_CUDA_GRAPHS
#include <ATen/cuda/CUDAEvent.h>

#include "cuda_graph_update.h"
#endif

namespace farm {

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

namespace {

// The update's loss, Q and target means, from the Q networks on a batch already on their device:
// Huber loss on the double-DQN (or plain) target, gradients clipped to max_grad_norm as
// torch::nn::utils::clip_grad_norm_ clips them but without reading the norm back to the host (so
// a CUDA graph can hold it), then `step` with the clipped gradients. Returns [loss, q mean, target
// mean] as one device tensor.
template <class Step>
torch::Tensor dqn_step(LinearMlp& online, LinearMlp& target_net, const config::DqnConfig& cfg, const SampledBatch& b,
                       const std::vector<torch::Tensor>& params, Step&& step) {
  const auto actions = b.actions.reshape({-1, 1}).round().to(torch::kLong);
  torch::Tensor target;
  {
    torch::NoGradGuard no_grad;
    const auto next_target = target_net->forward(b.next_obs);
    const auto next_online = cfg.double_q() ? online->forward(b.next_obs) : next_target;
    target = dqn_target(b.rewards, b.terminated, next_online, next_target, cfg.gamma(), cfg.double_q(), b.horizon);
  }
  const auto q = online->forward(b.obs).gather(1, actions).squeeze(1);
  const auto loss = torch::smooth_l1_loss(q, target);
  auto grads = torch::autograd::grad({loss}, params);
  torch::NoGradGuard no_grad;
  std::vector<torch::Tensor> norms;
  norms.reserve(grads.size());
  for (const auto& g : grads) norms.push_back(g.norm());
  const auto total = torch::stack(norms).norm();
  const auto coef = (cfg.max_grad_norm() / (total + 1e-6)).clamp_max(1.0);
  for (auto& g : grads) g.mul_(coef);
  step(grads);
  return torch::stack({loss.detach(), q.detach().mean(), target.mean()});
}

}  // namespace

struct Dqn::Impl {
  Impl(const config::DqnConfig& c, int obs, int actions)
      : cfg(c),
        obs_dim(obs),
        num_actions(actions),
        hidden(dqn_hidden(c)),
        device(learner_device(c.device(), "dqn.device")),
        online(sizes(), /*tanh_hidden=*/false),
        target(sizes(), /*tanh_hidden=*/false) {
    check_config(c);  // the loader's checks, for a config built in code
    if (obs < 1 || actions < 2) {
      throw std::invalid_argument("dqn: needs obs_dim >= 1 and >= 2 discrete actions, got " + std::to_string(obs) +
                                  " and " + std::to_string(actions));
    }
    for (LinearMlp* net : {&online, &target}) {
      (*net)->to(device);
      (*net)->compute = matmul_dtype_named(c.matmul_dtype(), "dqn");
      (*net)->pad_on_cuda = device.is_cuda();
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

  // The batch on the networks' device (a copy per field on a GPU).
  SampledBatch on_device(const SampledBatch& b) const {
    if (device.is_cpu()) return b;
    auto to = [&](const torch::Tensor& t) { return t.defined() ? t.to(device) : t; };
    return {to(b.obs), to(b.actions), to(b.rewards), to(b.terminated), to(b.next_obs), to(b.horizon)};
  }
  // Adam's rate: the configured one times lr_scale.
  void apply_learning_rate() {
    for (auto& g : opt->param_groups())
      static_cast<torch::optim::AdamOptions&>(g.options()).lr(cfg.learning_rate() * lr_scale);
  }
  // After an update: the target copy every target_update_updates updates.
  void count_update() {
    ++updates;
    if (updates % cfg.target_update_updates() == 0) copy_target();
  }

  config::DqnConfig cfg;
  int obs_dim, num_actions;
  std::vector<int> hidden;
  torch::Device device;
  LinearMlp online, target;
  std::unique_ptr<torch::optim::Adam> opt;
  double lr_scale = 1;
  int64_t updates = 0;

  // One update's input: a sampled batch (on the host or the networks' device), or, where `replay`
  // is set, `batch` rows drawn from it on the device.
  struct Input {
    SampledBatch sampled;
    const DeviceReplay* replay = nullptr;
    int64_t batch = 0;
  };
  // n updates on the inputs next() gives; each update's figures [loss, q mean, target mean] stay
  // on the device until all n are queued, then come back in one copy.
  std::vector<DqnStats> run(int n, const std::function<Input()>& next);
  torch::Tensor eager_step(const Input& in);
  torch::Tensor graph_step(const Input& in);

  bool use_graph() const;
  void drop_graph();  // after load(): the optimizer state it was captured with is replaced
#ifdef FARM_CUDA_GRAPHS
  struct Graph;
  struct GraphDeleter {
    void operator()(Graph* g) const;
  };
  std::unique_ptr<Graph, GraphDeleter> graph;
#endif
};

static const config::DqnConfig& seeded(const config::DqnConfig& cfg, uint64_t seed) {
  torch::manual_seed(seed);
  return cfg;
}

Dqn::Dqn(const config::DqnConfig& cfg, int obs_dim, int num_actions, uint64_t seed)
    : impl_(std::make_unique<Impl>(seeded(cfg, seed), obs_dim, num_actions)) {
  // A process-wide switch in LibTorch, as SAC sets it (sac.cuda_tf32): before the first update.
  if (impl_->device.is_cuda()) at::globalContext().setAllowTF32CuBLAS(cfg.cuda_tf32());
}
Dqn::~Dqn() = default;
Dqn::Dqn(Dqn&&) noexcept = default;
Dqn& Dqn::operator=(Dqn&&) noexcept = default;

DqnStats Dqn::update(const SampledBatch& batch) {
  return impl_->run(1, [&] { return Impl::Input{batch}; }).front();
}

std::vector<DqnStats> Dqn::update_n(int n, const std::function<SampledBatch()>& next_batch) {
  return impl_->run(n, [&] { return Impl::Input{next_batch()}; });
}

std::vector<DqnStats> Dqn::update_n_from(int n, int64_t batch, const DeviceReplay& replay) {
  require_same_device(replay, impl_->device, "dqn");
  if (n > 0 && replay.size() == 0)
    throw std::logic_error("dqn: no rows to draw minibatches from (the replay is empty)");
  return impl_->run(n, [&] { return Impl::Input{{}, &replay, batch}; });
}

std::vector<DqnStats> Dqn::Impl::run(int n, const std::function<Input()>& next) {
  std::vector<torch::Tensor> figures;
  figures.reserve(size_t(std::max(n, 0)));
  for (int i = 0; i < n; ++i) {
    const Input in = next();
    figures.push_back(use_graph() ? graph_step(in) : eager_step(in));
  }
  std::vector<DqnStats> out(figures.size());
  if (figures.empty()) return out;
  const auto all = torch::stack(figures).to(torch::kCPU, torch::kDouble).contiguous();  // the one wait on a GPU
  const double* f = all.data_ptr<double>();
  for (auto& st : out) {
    st.loss = f[0];
    st.q_mean = f[1];
    st.target_mean = f[2];
    f += 3;
  }
  return out;
}

torch::Tensor Dqn::Impl::eager_step(const Input& in) {
  const SampledBatch b = in.replay ? in.replay->sample(in.batch) : on_device(in.sampled);
  const auto params = online->parameters();
  const auto figures = dqn_step(online, target, cfg, b, params, [&](const std::vector<torch::Tensor>& grads) {
    for (size_t i = 0; i < params.size(); ++i) params[i].mutable_grad() = grads[i];
    opt->step();
  });
  count_update();
  return figures;
}

bool Dqn::uses_cuda_graph() const { return impl_->use_graph(); }
bool Dqn::on_gpu() const { return impl_->device.is_cuda(); }
torch::Device Dqn::device() const { return impl_->device; }

#ifdef FARM_CUDA_GRAPHS
// One update captured as a CUDA graph, as SAC's (sac_cuda_graph.cpp, which says more), for one
// batch size and one source: static device inputs that each update overwrites from a pinned host
// buffer, or (drawn_from set) rows drawn from a DeviceReplay inside the graph, from the default
// CUDA generator, whose philox offset each replay advances; Adam as GraphAdam; warm-ups and
// capture as run_graph_update does them. The target copy stays outside the graph, queued after the
// replay every target_update_updates updates. Replays are queued without waiting: each one's
// figures are copied on the device behind it, and Impl::run reads them all back at the end.
struct Dqn::Impl::Graph {
  static constexpr int kWarmupUpdates = 3;  // before the capture (run_graph_update)

  Graph(Impl& s, int64_t batch, const DeviceReplay* replay)
      : batch(batch),
        drawn_from(replay),
        device_index(s.device.has_index() ? s.device.index() : c10::cuda::current_device()),
        params(s.online->parameters()),
        adam(*s.opt, params),
        capture_stream(c10::cuda::getStreamFromPool(false, device_index)) {
    if (replay) return;
    const int64_t o = s.obs_dim;
    widths = {o, 1, 1, 1, o, 1};
    const auto f32 = torch::TensorOptions().dtype(torch::kFloat);
    int64_t n = 0;
    for (int64_t w : widths) n += batch * w;
    for (auto& h : host_in) h = torch::empty({n}, f32.pinned_memory(true));
    dev_in = torch::empty({n}, f32.device(s.device));
    std::array<torch::Tensor*, 6> views{&in.obs, &in.actions, &in.rewards, &in.terminated, &in.next_obs, &in.horizon};
    int64_t offset = 0;
    for (size_t i = 0; i < views.size(); ++i) {
      const int64_t k = batch * widths[i];
      *views[i] = widths[i] == 1 ? dev_in.narrow(0, offset, k) : dev_in.narrow(0, offset, k).view({batch, widths[i]});
      offset += k;
    }
  }

  // The sampled batch into the next pinned buffer (once the copy from its previous batch is done),
  // then one copy to the static inputs on the current stream, behind the replays queued before it.
  // A batch without a horizon spans one step a row.
  void stage(const SampledBatch& b) {
    const int slot = next_host;
    next_host = (slot + 1) % int(host_in.size());
    staged[slot].synchronize();
    const std::array<const torch::Tensor*, 6> fields{&b.obs,        &b.actions,  &b.rewards,
                                                     &b.terminated, &b.next_obs, &b.horizon};
    float* dst = host_in[slot].data_ptr<float>();
    for (size_t i = 0; i < fields.size(); ++i) {
      const int64_t n = batch * widths[i];
      if (!fields[i]->defined() && i == 5) {
        std::fill(dst, dst + n, 1.f);
      } else {
        const torch::Tensor t = fields[i]->to(torch::kCPU, torch::kFloat).contiguous();
        if (t.numel() != n)
          throw std::invalid_argument("dqn update: batch field " + std::to_string(i) + " has " +
                                      std::to_string(t.numel()) + " values, expected " + std::to_string(n));
        std::memcpy(dst, t.data_ptr<float>(), sizeof(float) * n);
      }
      dst += n;
    }
    dev_in.copy_(host_in[slot], /*non_blocking=*/true);
    staged[slot].record(c10::cuda::getCurrentCUDAStream(device_index));
  }

  void body(Impl& s) {
    adam.advance_device_steps();
    SampledBatch b = in;
    if (drawn_from)
      b = drawn_from->draw(torch::rand({batch}, torch::TensorOptions().dtype(torch::kDouble).device(s.device)));
    out = dqn_step(s.online, s.target, s.cfg, b, params,
                   [&](const std::vector<torch::Tensor>& grads) { adam.step(grads); });
  }

  int64_t batch;
  const DeviceReplay* drawn_from;  // where the graph draws its batch; null: staged from the host
  c10::DeviceIndex device_index;
  std::array<int64_t, 6> widths{};
  std::vector<torch::Tensor> params;
  GraphAdam adam;
  c10::cuda::CUDAStream capture_stream;
  // Two pinned buffers: the host fills one while the copy from the other may still be queued.
  std::array<torch::Tensor, 2> host_in;
  std::array<at::cuda::CUDAEvent, 2> staged;
  int next_host = 0;
  torch::Tensor dev_in, out;
  SampledBatch in;
  std::unique_ptr<at::cuda::CUDAGraph> graph;
  int warmups_left = kWarmupUpdates;
};

void Dqn::Impl::GraphDeleter::operator()(Graph* g) const { delete g; }
#endif

bool Dqn::Impl::use_graph() const {
#ifdef FARM_CUDA_GRAPHS
  return device.is_cuda() && cfg.cuda_graph();
#else
  return false;
#endif
}

torch::Tensor Dqn::Impl::graph_step(const Input& in) {
#ifdef FARM_CUDA_GRAPHS
  const int64_t b = in.replay ? in.batch : in.sampled.obs.size(0);
  if (!graph || graph->batch != b || graph->drawn_from != in.replay) {
    // Replays queued on the old graph use its memory: they finish before it goes, and its private
    // memory pool goes before the next graph's.
    if (graph) c10::cuda::getCurrentCUDAStream(graph->device_index).synchronize();
    graph.reset();
    graph.reset(new Graph(*this, b, in.replay));
  }
  Graph& g = *graph;
  c10::cuda::CUDAGuard device_guard(g.device_index);
  if (!in.replay) g.stage(in.sampled);
  run_graph_update(g.graph, g.warmups_left, g.device_index, g.capture_stream, [&] { g.body(*this); });
  auto figures = g.out.clone();  // behind the replay, before the next one overwrites `out`
  g.adam.advance_host_steps();
  count_update();  // the target copy, where due, queued after the replay
  return figures;
#else
  (void)in;
  throw std::logic_error("dqn: CUDA graph update in a build without CUDA");
#endif
}

void Dqn::Impl::drop_graph() {
#ifdef FARM_CUDA_GRAPHS
  graph.reset();
#endif
}

void Dqn::scale_learning_rate(double factor) {
  if (!(factor > 0) || !std::isfinite(factor))
    throw std::invalid_argument("dqn: learning-rate scale must be a finite number > 0, got " + std::to_string(factor));
  Impl& s = *impl_;
  if (factor == s.lr_scale) return;
  s.lr_scale = factor;
  s.apply_learning_rate();
  s.drop_graph();  // a captured graph holds the rate it was captured with
}

double Dqn::learning_rate() const {
  return static_cast<const torch::optim::AdamOptions&>(impl_->opt->param_groups()[0].options()).lr();
}

double Dqn::epsilon() const { return dqn_epsilon(impl_->cfg, env_steps_); }

PolicyParams Dqn::export_policy(uint64_t version) const {
  const Impl& s = *impl_;
  PolicyParams p = dqn_policy_shape(s.obs_dim, s.num_actions, s.cfg);
  p.version = version;
  p.epsilon = float(epsilon());
  for (const auto& layer : s.online->layers) {
    const auto w = layer->weight.detach().to(torch::kCPU).contiguous();
    const auto b = layer->bias.detach().to(torch::kCPU).contiguous();
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
  return impl_->online->forward(obs.to(impl_->device)).to(obs.device());
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
    root.load_from(file, s.device);  // whatever device wrote it
    torch::Tensor meta;
    root.read("meta", meta);
    std::vector<int64_t> want{s.obs_dim, s.num_actions};
    want.insert(want.end(), s.hidden.begin(), s.hidden.end());
    const auto m = meta.to(torch::kCPU, torch::kInt64).contiguous();
    if (std::vector<int64_t>(m.data_ptr<int64_t>(), m.data_ptr<int64_t>() + m.numel()) != want) {
      throw std::runtime_error("dqn checkpoint " + file +
                               ": network sizes (obs, actions, hidden...) differ from this config");
    }
    // Into fresh networks first, so a failed read leaves this instance as it was.
    LinearMlp online(s.sizes(), false), target(s.sizes(), false);
    online->to(s.device);
    target->to(s.device);
    torch::serialize::InputArchive a, b, o;
    root.read("online", a);
    root.read("target", b);
    online->load(a);
    target->load(b);
    s.drop_graph();  // captured with the optimizer state that the load replaces
    torch::NoGradGuard no_grad;
    auto copy = [](LinearMlp& from, LinearMlp& to) {
      auto src = from->parameters(), dst = to->parameters();
      for (size_t i = 0; i < src.size(); ++i) dst[i].copy_(src[i]);
    };
    copy(online, s.online);
    copy(target, s.target);
    root.read("optim", o);
    s.opt->load(o);
    s.apply_learning_rate();  // this instance's rate, whatever rate the saved state holds
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
