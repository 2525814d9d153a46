// farm._farm: the farm's C++ parts for Python. A vector of environments of any task the farm runs
// (the C++ VecEnv, stepped by a thread pool with the GIL released), a trained policy as the
// workers compute it (policy.bin), and a checkpoint manifest as JSON. The Python package
// (python/farm/) wraps these in Gymnasium's conventions.
#include <google/protobuf/text_format.h>
#include <google/protobuf/util/json_util.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>
#include <nlohmann/json.hpp>

#include <atomic>
#include <cmath>
#include <condition_variable>
#include <filesystem>
#include <fstream>
#include <memory>
#include <mutex>
#include <optional>
#include <random>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "config.h"
#include "farm_config.pb.h"
#include "mlp.h"
#include "policy_file.h"
#include "task.h"
#include "task_specs.h"
#include "vec_env.h"

namespace py = pybind11;
namespace fs = std::filesystem;

namespace {

// The task a config names: a config file (its task section, files of a task of terms read from
// its folder), or a task name with that task's defaults.
std::shared_ptr<const farm::robots::Task> task_of(const std::string& config) {
  farm::config::TaskConfig task;
  if (fs::is_regular_file(config)) {
    task = farm::robots::load_config_file(config).task();
  } else if (config.find('/') != std::string::npos ||
             (config.size() > 7 && config.substr(config.size() - 7) == ".txtpb")) {
    throw std::invalid_argument("no config file " + config);
  } else {
    task =
        farm::robots::parse_config_text("experiment_id: \"python\" task { name: \"" + config + "\" }", config).task();
  }
  return std::shared_ptr<const farm::robots::Task>(farm::robots::make_task(task));
}

// N environments stepped by `threads` threads (the calling one among them), each owning a
// contiguous range of envs, as a worker's rollout splits them.
class VecEnvPy {
 public:
  VecEnvPy(const std::string& config, int num_envs, int threads, uint64_t seed)
      : env_(task_of(config), num_envs, seed), threads_(std::clamp(threads, 1, num_envs)) {
    if (threads < 1) throw std::invalid_argument("threads must be >= 1, got " + std::to_string(threads));
    const int n = env_.num_envs();
    rewards_.assign(n, 0.f);
    terminated_.assign(n, 0);
    truncated_.assign(n, 0);
    actions_.assign(size_t(n) * env_.act_dim(), 0.f);
    for (int k = 0; k < threads_; ++k) {
      Chunk c;
      c.begin = int(int64_t(n) * k / threads_);
      c.end = int(int64_t(n) * (k + 1) / threads_);
      chunks_.push_back(std::move(c));
    }
    for (int k = 1; k < threads_; ++k) pool_.emplace_back([this, k] { thread_main(k); });
  }
  ~VecEnvPy() {
    {
      std::lock_guard<std::mutex> lk(mu_);
      stop_.store(true);
    }
    start_cv_.notify_all();
    for (auto& t : pool_) t.join();
  }

  int num_envs() const { return env_.num_envs(); }
  int obs_dim() const { return env_.obs_dim(); }
  int act_dim() const { return env_.act_dim(); }
  int num_actions() const { return env_.spec().num_actions; }
  int threads() const { return threads_; }
  std::vector<std::string> metric_names() const { return env_.spec().metric_names; }

  // Views of the C++ buffers, kept alive by this object; the next step or reset overwrites them.
  py::array obs(py::handle self) const {
    return py::array_t<float>({env_.num_envs(), env_.obs_dim()}, env_.obs(), self);
  }
  py::array rewards(py::handle self) const { return py::array_t<float>({env_.num_envs()}, rewards_.data(), self); }
  py::array terminated(py::handle self) const { return flags(terminated_, self); }
  py::array truncated(py::handle self) const { return flags(truncated_, self); }

  void reset(std::optional<uint64_t> seed) {
    if (seed) env_.reseed(*seed);
    py::gil_scoped_release nogil;
    env_.reset_all();
  }

  // Starts a new episode in each env of `envs` alone (Gymnasium's partial reset); where its entry of
  // `seeds` holds a seed, that env's seed generator is restarted with it and its entry of `streams`
  // first (reseed_env).
  void reset_envs(const std::vector<int>& envs, const std::vector<std::optional<uint64_t>>& seeds,
                  const std::vector<uint64_t>& streams) {
    if (seeds.size() != envs.size() || streams.size() != envs.size())
      throw py::value_error("reset_envs: " + std::to_string(envs.size()) + " envs but " + std::to_string(seeds.size()) +
                            " seeds and " + std::to_string(streams.size()) + " streams");
    for (int e : envs)
      if (e < 0 || e >= env_.num_envs())
        throw py::value_error("reset_envs: env " + std::to_string(e) + " outside [0, " +
                              std::to_string(env_.num_envs()) + ")");
    py::gil_scoped_release nogil;
    for (size_t k = 0; k < envs.size(); ++k) {
      if (seeds[k]) env_.reseed_env(envs[k], *seeds[k], streams[k]);
      env_.reset(envs[k]);
    }
  }

  // Copies actions in (checked against the shape and dtype the task takes), then steps every env
  // with the GIL released; envs where `skip` (bool, one per env) is true are not stepped: their
  // observation stays, their reward and flags are 0 (Gymnasium's next-step autoreset, the step that
  // hands out the first observation of the episode the env already started).
  void step(py::array actions, std::optional<py::array_t<bool, py::array::c_style | py::array::forcecast>> skip) {
    const int n = env_.num_envs();
    const bool discrete = num_actions() > 0;
    const std::string want =
        discrete ? "(" + std::to_string(n) + ",) of integers in [0, " + std::to_string(num_actions()) + ")"
                 : "(" + std::to_string(n) + ", " + std::to_string(act_dim()) + ") of float32";
    auto bad = [&](const std::string& what) {
      return py::value_error("actions: expected shape " + want + ", got " + what);
    };
    std::string got_shape = "(";
    for (py::ssize_t d = 0; d < actions.ndim(); ++d) got_shape += (d ? ", " : "") + std::to_string(actions.shape(d));
    got_shape += actions.ndim() == 1 ? ",)" : ")";
    const std::string got = got_shape + " of " + std::string(py::str(actions.dtype()));
    if (discrete) {
      if (actions.ndim() != 1 || actions.shape(0) != n) throw bad(got);
      if (actions.dtype().kind() != 'i' && actions.dtype().kind() != 'u') throw bad(got);
      auto a = py::array_t<int64_t, py::array::c_style | py::array::forcecast>::ensure(actions);
      const int64_t* p = a.data();
      for (int i = 0; i < n; ++i) {
        if (p[i] < 0 || p[i] >= num_actions())
          throw py::value_error("actions: entry " + std::to_string(i) + " is " + std::to_string(p[i]) +
                                ", outside [0, " + std::to_string(num_actions()) + ")");
        actions_[i] = float(p[i]);
      }
    } else {
      if (actions.ndim() != 2 || actions.shape(0) != n || actions.shape(1) != act_dim()) throw bad(got);
      if (!actions.dtype().is(py::dtype::of<float>())) throw bad(got);
      auto a = py::array_t<float, py::array::c_style | py::array::forcecast>::ensure(actions);
      for (size_t i = 0; i < size_t(n) * act_dim(); ++i)
        if (!std::isfinite(a.data()[i]))
          throw py::value_error("actions: entry " + std::to_string(i / act_dim()) + ", " +
                                std::to_string(i % act_dim()) + " is " + std::to_string(a.data()[i]) +
                                ", not a finite number");
      std::copy(a.data(), a.data() + size_t(n) * act_dim(), actions_.begin());
    }
    skip_.assign(n, 0);
    if (skip) {
      if (skip->ndim() != 1 || skip->shape(0) != n)
        throw py::value_error("skip: expected a bool array of shape (" + std::to_string(n) + ",)");
      for (int i = 0; i < n; ++i) skip_[i] = skip->data()[i] ? 1 : 0;
    }
    py::gil_scoped_release nogil;
    run_all();
  }

  // The episodes that ended in the last step: (env, return, length, terminated, final obs, metrics);
  // None when none did (most steps), so a step makes no arrays for them.
  py::object ended() const {
    bool any = false;
    for (const Chunk& c : chunks_) any = any || c.ends.size() > 0;
    if (!any) return py::none();
    std::vector<int> env;
    std::vector<float> ret, final_obs, metrics;
    std::vector<int> length;
    std::vector<uint8_t> term;
    const int m = int(env_.spec().metric_names.size());
    for (const Chunk& c : chunks_) {
      for (int i = 0; i < c.ends.size(); ++i) {
        const farm::EpisodeRecord& r = c.ends.record(i);
        env.push_back(r.env);
        ret.push_back(r.episode_return);
        length.push_back(r.length);
        term.push_back(r.terminated);
        final_obs.insert(final_obs.end(), c.ends.final_obs(i), c.ends.final_obs(i) + env_.obs_dim());
        for (int k = 0; k < m; ++k) metrics.push_back(k < int(r.metrics.size()) ? r.metrics[k] : 0.f);
      }
    }
    const py::ssize_t e = py::ssize_t(env.size());
    py::dict d;
    d["env"] = py::array_t<int>(e, env.data());
    d["episode_return"] = py::array_t<float>(e, ret.data());
    d["episode_length"] = py::array_t<int>(e, length.data());
    d["terminated"] = py::array_t<bool>(e, reinterpret_cast<const bool*>(term.data()));
    d["final_obs"] = py::array_t<float>({e, py::ssize_t(env_.obs_dim())}, final_obs.data());
    d["metrics"] = py::array_t<float>({e, py::ssize_t(m)}, metrics.data());
    return d;
  }

 private:
  struct Chunk {
    int begin = 0, end = 0;
    farm::EpisodeEnds ends;
  };

  static py::array flags(const std::vector<uint8_t>& v, py::handle self) {
    return py::array(py::dtype::of<bool>(), {py::ssize_t(v.size())}, {py::ssize_t(1)}, v.data(), self);
  }

  // Steps the chunk's envs, in runs of envs not skipped.
  void step_chunk(Chunk& c) {
    c.ends.clear();
    for (int i = c.begin; i < c.end;) {
      if (skip_[i]) {
        rewards_[i] = 0.f;
        terminated_[i] = truncated_[i] = 0;
        ++i;
        continue;
      }
      int j = i;
      while (j < c.end && !skip_[j]) ++j;
      env_.step_range(i, j, actions_.data(), rewards_.data(), terminated_.data(), truncated_.data(), c.ends);
      i = j;
    }
  }

  // Spins for up to about half a millisecond until done() holds (the time a step's Python around it
  // takes), so that a step hands over to the pool's threads without waking them from sleep.
  template <class F>
  static bool spin_until(F done) {
    for (int i = 0; i < 20000; ++i) {
      if (done()) return true;
      __builtin_ia32_pause();
    }
    return done();
  }

  void run_all() {
    error_ = nullptr;
    pending_.store(threads_ - 1);
    {
      std::lock_guard<std::mutex> lk(mu_);
      generation_.fetch_add(1);
    }
    start_cv_.notify_all();
    std::exception_ptr mine;
    try {
      step_chunk(chunks_[0]);
    } catch (...) {
      mine = std::current_exception();
    }
    if (!spin_until([&] { return pending_.load() == 0; })) {
      std::unique_lock<std::mutex> lk(mu_);
      done_cv_.wait(lk, [&] { return pending_.load() == 0; });
    }
    if (mine) std::rethrow_exception(mine);
    std::lock_guard<std::mutex> lk(mu_);
    if (error_) std::rethrow_exception(error_);
  }

  void thread_main(int k) {
    uint64_t seen = 0;
    for (;;) {
      auto woken = [&] { return stop_.load() || generation_.load() != seen; };
      if (!spin_until(woken)) {
        std::unique_lock<std::mutex> lk(mu_);
        start_cv_.wait(lk, woken);
      }
      if (stop_.load()) return;
      seen = generation_.load();
      std::exception_ptr err;
      try {
        step_chunk(chunks_[k]);
      } catch (...) {
        err = std::current_exception();
      }
      if (err) {
        std::lock_guard<std::mutex> lk(mu_);
        if (!error_) error_ = err;
      }
      if (pending_.fetch_sub(1) == 1) {
        std::lock_guard<std::mutex> lk(mu_);  // the waiter checks pending_ under mu_: no lost wake-up
        done_cv_.notify_all();
      }
    }
  }

  farm::VecEnv env_;
  int threads_;
  std::vector<float> actions_, rewards_;
  std::vector<uint8_t> terminated_, truncated_, skip_;
  std::vector<Chunk> chunks_;
  std::vector<std::thread> pool_;
  std::mutex mu_;
  std::condition_variable start_cv_, done_cv_;
  std::atomic<uint64_t> generation_{0};
  std::atomic<int> pending_{0};
  std::atomic<bool> stop_{false};
  std::exception_ptr error_;  // under mu_
};

// A trained policy as the workers run it in evaluations: the deterministic action (the mode).
class PolicyPy {
 public:
  explicit PolicyPy(const std::string& path) {
    const fs::path p = fs::is_directory(path) ? fs::path(path) / farm::kPolicyFileName : fs::path(path);
    params_ = farm::read_policy_file(p.string());
    policy_ = farm::Policy(params_);
  }
  int obs_dim() const { return policy_.obs_dim(); }
  int act_dim() const { return policy_.act_dim(); }
  int num_actions() const { return policy_.num_actions(); }
  uint64_t version() const { return params_.version; }
  std::string describe() const { return params_.layout.describe(); }

  py::array act(py::array_t<float, py::array::c_style | py::array::forcecast> obs) {
    const bool single = obs.ndim() == 1;
    if ((obs.ndim() != 1 && obs.ndim() != 2) || obs.shape(obs.ndim() - 1) != obs_dim())
      throw py::value_error("observation: expected shape (" + std::to_string(obs_dim()) + ",) or (rows, " +
                            std::to_string(obs_dim()) + ")");
    const int rows = single ? 1 : int(obs.shape(0));
    std::vector<float> out(size_t(rows) * act_dim());
    for (py::ssize_t i = 0; i < obs.size(); ++i)
      if (!std::isfinite(obs.data()[i]))
        throw py::value_error("observation: entry " + std::to_string(i / obs_dim()) + ", " +
                              std::to_string(i % obs_dim()) + " is " + std::to_string(obs.data()[i]) +
                              ", not a finite number");
    {
      py::gil_scoped_release nogil;
      // The policy's scratch buffers are its own: one call at a time, from whichever thread.
      std::lock_guard<std::mutex> lk(mu_);
      policy_.act(obs.data(), rows, rng_, true, out.data(), nullptr);
    }
    if (num_actions() > 0) {
      std::vector<int64_t> idx(out.begin(), out.end());
      if (single) return py::array_t<int64_t>(std::vector<py::ssize_t>{}, idx.data());  // 0-d: one action
      return py::array_t<int64_t>(py::ssize_t(rows), idx.data());
    }
    if (single) return py::array_t<float>(py::ssize_t(act_dim()), out.data());
    return py::array_t<float>({py::ssize_t(rows), py::ssize_t(act_dim())}, out.data());
  }

  // The layout and numbers, for checking or for building a PyTorch module from them.
  py::dict params() const {
    py::dict d;
    d["version"] = params_.version;
    d["head"] = int(params_.head);
    d["sizes"] = params_.layout.sizes;
    d["activation"] = int(params_.layout.activation);
    d["obs_mean"] = params_.obs_mean;
    d["obs_std"] = params_.obs_std;
    d["params"] = py::array_t<float>(py::ssize_t(params_.params.size()), params_.params.data());
    d["log_std"] = params_.log_std;
    d["log_std_min"] = params_.log_std_min;
    d["log_std_max"] = params_.log_std_max;
    d["epsilon"] = params_.epsilon;
    return d;
  }

 private:
  farm::PolicyParams params_;
  farm::Policy policy_;
  std::mt19937_64 rng_;
  std::mutex mu_;  // act(): policy_'s scratch buffers and rng_
};

// protobuf's JSON printer writes 64-bit integers as strings (JavaScript's numbers hold 53 bits);
// Python's ints hold them all, so they become numbers again, in nested messages too.
void int64_as_numbers(const google::protobuf::Descriptor* d, nlohmann::json& j) {
  using FD = google::protobuf::FieldDescriptor;
  for (int i = 0; i < d->field_count(); ++i) {
    const FD* f = d->field(i);
    auto it = j.find(f->name());
    if (it == j.end() || f->is_map()) continue;
    const auto fix = [&](nlohmann::json& v) {
      if (f->cpp_type() == FD::CPPTYPE_INT64 && v.is_string()) v = std::stoll(v.get<std::string>());
      if (f->cpp_type() == FD::CPPTYPE_UINT64 && v.is_string()) v = std::stoull(v.get<std::string>());
      if (f->cpp_type() == FD::CPPTYPE_MESSAGE && v.is_object()) int64_as_numbers(f->message_type(), v);
    };
    if (it->is_array()) {
      for (auto& v : *it) fix(v);
    } else {
      fix(*it);
    }
  }
}

std::string manifest_json(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error("cannot read " + path);
  std::stringstream text;
  text << in.rdbuf();
  farm::config::CheckpointManifest m;
  if (!google::protobuf::TextFormat::ParseFromString(text.str(), &m))
    throw std::runtime_error(path + " is not a checkpoint manifest");
  std::string json;
  google::protobuf::util::JsonPrintOptions o;
  o.preserve_proto_field_names = true;
  google::protobuf::util::MessageToJsonString(m, &json, o);
  nlohmann::json j = nlohmann::json::parse(json);
  int64_as_numbers(m.GetDescriptor(), j);
  return j.dump();
}

}  // namespace

#ifdef FARM_WITH_DDS
void add_learner_bus(py::module_& m);  // learner_bus.cpp
#endif

PYBIND11_MODULE(_farm, m) {
  m.doc() = "The farm's C++ vector environments, policies and manifests (see the farm package)";
  m.def("task_names", &farm::robots::task_names, "The tasks this build of the farm runs");
  m.def("manifest_json", &manifest_json, py::arg("path"), "A checkpoint's manifest.txtpb as JSON text");
  py::register_exception<farm::ConfigError>(m, "ConfigError", PyExc_ValueError);

  py::class_<VecEnvPy>(m, "VecEnvCore")
      .def(py::init<const std::string&, int, int, uint64_t>(), py::arg("config"), py::arg("num_envs"),
           py::arg("threads"), py::arg("seed"))
      .def_property_readonly("num_envs", &VecEnvPy::num_envs)
      .def_property_readonly("obs_dim", &VecEnvPy::obs_dim)
      .def_property_readonly("act_dim", &VecEnvPy::act_dim)
      .def_property_readonly("num_actions", &VecEnvPy::num_actions)
      .def_property_readonly("threads", &VecEnvPy::threads)
      .def_property_readonly("metric_names", &VecEnvPy::metric_names)
      .def("obs", [](py::object self) { return self.cast<VecEnvPy&>().obs(self); })
      .def("rewards", [](py::object self) { return self.cast<VecEnvPy&>().rewards(self); })
      .def("terminated", [](py::object self) { return self.cast<VecEnvPy&>().terminated(self); })
      .def("truncated", [](py::object self) { return self.cast<VecEnvPy&>().truncated(self); })
      .def("reset", &VecEnvPy::reset, py::arg("seed") = py::none())
      .def("reset_envs", &VecEnvPy::reset_envs, py::arg("envs"), py::arg("seeds"), py::arg("streams"))
      .def("step", &VecEnvPy::step, py::arg("actions"), py::arg("skip") = py::none())
      .def("ended", &VecEnvPy::ended);

  py::class_<PolicyPy>(m, "PolicyCore")
      .def(py::init<const std::string&>(), py::arg("path"))
      .def_property_readonly("obs_dim", &PolicyPy::obs_dim)
      .def_property_readonly("act_dim", &PolicyPy::act_dim)
      .def_property_readonly("num_actions", &PolicyPy::num_actions)
      .def_property_readonly("version", &PolicyPy::version)
      .def("describe", &PolicyPy::describe)
      .def("act", &PolicyPy::act, py::arg("obs"))
      .def("params", &PolicyPy::params);
#ifdef FARM_WITH_DDS
  add_learner_bus(m);
#endif
}
