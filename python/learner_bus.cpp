// farm._farm.LearnerBus: the learner's side of the bus for an algorithm written in Python. It
// publishes an experiment's spec, takes the workers' batches through the learner's own ingest
// thread (checked and accounted per worker stream as farm-learner does: lost, duplicate, invalid)
// and hands them over as NumPy arrays, and publishes policies.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <memory>
#include <set>
#include <string>
#include <vector>

#include "config.h"
#include "config_validator.h"
#include "dds.h"
#include "eval_answer.h"
#include "events.h"
#include "ingest.h"
#include "ingest_thread.h"
#include "meter.h"
#include "mlp.h"
#include "roster_thread.h"
#include "spec_publisher.h"
#include "task_specs.h"
#include "weight_publisher.h"

namespace py = pybind11;

namespace {

template <class T>
py::array_t<T> array_of(const std::vector<T>& v, std::vector<py::ssize_t> shape) {
  py::array_t<T> a(shape);
  std::copy(v.begin(), v.end(), a.mutable_data());
  return a;
}

// A text off the wire (a worker id) as a Python str: bytes that are not UTF-8 become backslash
// escapes, so a worker's odd id cannot fail the call that reports it (and lose what it took).
py::str wire_text(const std::string& s) {
  PyObject* o = PyUnicode_DecodeUTF8(s.data(), py::ssize_t(s.size()), "backslashreplace");
  if (!o) throw py::error_already_set();
  return py::reinterpret_steal<py::str>(o);
}

class LearnerBus {
 public:
  LearnerBus(const std::string& config, int domain, const std::string& profiles, const std::string& events_path)
      : cfg_(farm::robots::load_config_file(config)),
        task_(farm::robots::task_spec(cfg_.task())),
        bus_(
            [&] {
              farm::dds::BusOptions o;
              o.domain = domain;
              o.profiles_file = profiles;
              return o;
            }(),
            "farm-python-learner"),
        spec_(bus_, cfg_, task_.obs_dim, task_.act_dim),
        weights_(bus_, cfg_.experiment_id()),
        intake_(
            bus_,
            [&] {
              farm::Ingest in(cfg_.experiment_id(), task_.obs_dim, task_.act_dim, int(task_.metric_names.size()));
              in.set_num_actions(task_.num_actions);
              in.set_reward_bound(task_.reward_bound, task_.reward_min, task_.reward_max);
              in.set_max_episode_steps(task_.max_episode_steps);
              return in;
            }(),
            uint32_t(std::min<uint64_t>(
                farm::Ingest::max_batch_bytes(task_.obs_dim, task_.act_dim, int(task_.metric_names.size()),
                                              cfg_.worker().steps_per_batch()),
                UINT32_MAX)),
            size_t(cfg_.ingest_queue_mib() * (1 << 20)),
            [](const std::string& m) { std::fprintf(stderr, "[learner-bus] %s\n", m.c_str()); }, events_),
        roster_(
            bus_,
            [&] {
              farm::WorkerRoster r(
                  cfg_.worker_timeout_seconds(),
                  [](const std::string& m) { std::fprintf(stderr, "[learner-bus] %s\n", m.c_str()); },
                  cfg_.experiment_id(), cfg_.account_expiry_seconds());
              r.on_event([this](const nlohmann::json& e) { events_.write("worker", e); });
              return r;
            }(),
            [](const std::string& m) { std::fprintf(stderr, "[learner-bus] %s\n", m.c_str()); }, events_),
        eval_out_(bus_, farm::dds::kEvalRequestTopic, "batch_writer"),
        eval_in_(bus_, farm::dds::kEvalAnswerTopic, "batch_reader",
                 farm::max_eval_answer_bytes(cfg_.experiment_id().size(),
                                             std::max(cfg_.eval().episodes(), cfg_.eval().final_episodes()),
                                             int(task_.metric_names.size()))) {
    if (!events_path.empty()) events_.open(events_path);
    events_.set_start(farm::now_seconds());
    intake_.start(0);  // no policy yet: the first is the caller's publish
    roster_.start();
    spec_.publish(false);
  }
  ~LearnerBus() { finish(); }

  int obs_dim() const { return task_.obs_dim; }
  int act_dim() const { return task_.act_dim; }
  int num_actions() const { return task_.num_actions; }
  std::string experiment_id() const { return cfg_.experiment_id(); }
  int domain() const { return bus_.domain(); }

  // Up to max_batches accepted batches, waiting up to timeout seconds for the first. Each is a
  // dict of NumPy arrays over its T*N rows (obs, actions, rewards, next_obs, terminated, truncated,
  // log_probs) with its worker, policy version and the episodes that ended in it.
  py::list take(int max_batches, double timeout) {
    std::vector<std::unique_ptr<farm::AcceptedBatch>> got;
    {
      py::gil_scoped_release nogil;
      spec_.republish_if_due(farm::now_seconds());
      weights_.republish_if_due(farm::now_seconds());
      const auto keep = [&](farm::AcceptedBatch& a) {
        got.push_back(std::make_unique<farm::AcceptedBatch>(std::move(a)));
      };
      if (intake_.pop(size_t(max_batches), keep) == 0 && timeout > 0) {
        intake_.wait(timeout);
        intake_.pop(size_t(max_batches), keep);
      }
    }
    py::list out;
    for (const auto& a : got) {
      const farm::Transitions& r = a->rows;
      const py::ssize_t n = r.n, od = task_.obs_dim, ad = task_.act_dim;
      py::dict d;
      d["worker_id"] = wire_text(a->worker_id);
      d["policy_version"] = a->policy_version;
      d["num_steps"] = a->num_steps;
      d["num_envs"] = a->num_envs;
      d["obs"] = array_of(r.obs, {n, od});
      d["actions"] = array_of(r.actions, {n, ad});
      d["rewards"] = array_of(r.rewards, {n});
      d["next_obs"] = array_of(r.next_obs, {n, od});
      py::array_t<bool> term(n);
      for (py::ssize_t i = 0; i < n; ++i) term.mutable_data()[i] = r.terminated[i] != 0;
      d["terminated"] = term;
      py::array_t<bool> trunc(py::ssize_t(a->truncated.size()));
      for (size_t i = 0; i < a->truncated.size(); ++i) trunc.mutable_data()[i] = a->truncated[i] != 0;
      d["truncated"] = trunc;
      d["log_probs"] = array_of(a->log_probs, {py::ssize_t(a->log_probs.size())});
      std::vector<float> returns;
      for (const auto& e : a->episodes) returns.push_back(e.episode_return);
      d["episode_returns"] = array_of(returns, {py::ssize_t(returns.size())});
      out.append(d);
    }
    return out;
  }

  // Publishes a policy in the workers' layout: version (> the last), sizes, activation (0 relu,
  // 1 tanh, 2 elu), head (0 squashed Gaussian, 1 Gaussian, 2 discrete Q), flat params (per layer
  // weight [out x in] then bias), and optionally obs_mean/obs_std, log_std, log_std_min/max and
  // epsilon (a discrete Q head's exploration probability on the workers). Any other key is refused.
  void publish(const py::dict& p) {
    const farm::PolicyParams pp = params_of(p);
    if (pp.version <= version_)
      throw py::value_error("policy version " + std::to_string(pp.version) + " is not newer than the last published, " +
                            std::to_string(version_));
    intake_.set_version(pp.version);
    version_ = pp.version;
    weights_.publish(pp, 0);
  }

 private:
  // A policy dict (publish()) as the workers' PolicyParams, checked as a worker checks one.
  farm::PolicyParams params_of(const py::dict& p) const {
    static const std::set<std::string> known = {"version",     "sizes",       "activation", "head",
                                                "params",      "obs_mean",    "obs_std",    "log_std",
                                                "log_std_min", "log_std_max", "epsilon"};
    for (const auto& item : p) {
      const std::string key = py::str(item.first);
      if (!known.count(key))
        throw py::value_error("policy: unknown key '" + key +
                              "' (known: version, sizes, activation, head, params, obs_mean, obs_std, log_std, "
                              "log_std_min, log_std_max, epsilon)");
    }
    farm::PolicyParams pp;
    pp.version = p["version"].cast<uint64_t>();
    pp.layout.sizes = p["sizes"].cast<std::vector<int>>();
    pp.layout.activation = farm::Activation(p.contains("activation") ? p["activation"].cast<int>() : 0);
    pp.head = farm::PolicyHead(p.contains("head") ? p["head"].cast<int>() : 0);
    pp.params = p["params"].cast<std::vector<float>>();
    if (p.contains("obs_mean")) pp.obs_mean = p["obs_mean"].cast<std::vector<float>>();
    if (p.contains("obs_std")) pp.obs_std = p["obs_std"].cast<std::vector<float>>();
    if (p.contains("log_std")) pp.log_std = p["log_std"].cast<std::vector<float>>();
    if (p.contains("log_std_min")) pp.log_std_min = p["log_std_min"].cast<float>();
    if (p.contains("log_std_max")) pp.log_std_max = p["log_std_max"].cast<float>();
    if (p.contains("epsilon")) pp.epsilon = p["epsilon"].cast<float>();  // a DQN policy's exploration
    try {
      farm::Policy check(pp);  // the workers' own consistency checks, before it goes out
      if (check.obs_dim() != task_.obs_dim || check.act_dim() != task_.act_dim)
        throw std::invalid_argument("the policy maps " + std::to_string(check.obs_dim()) + " observations to " +
                                    std::to_string(check.act_dim()) + " actions; the task has " +
                                    std::to_string(task_.obs_dim) + " and " + std::to_string(task_.act_dim));
    } catch (const std::invalid_argument& e) {
      throw py::value_error(std::string("policy: ") + e.what());
    }
    return pp;
  }

 public:
  // Batches and env steps accepted, and what was lost, duplicated or invalid, over every stream;
  // per stream in "workers".
  py::dict counters() {
    py::dict d;
    intake_.with_ingest([&](farm::Ingest& in) {
      const farm::IngestCounters& c = in.counters();
      d["batches_ok"] = c.ok;
      d["batches_lost"] = c.lost;
      d["batches_duplicate"] = c.duplicate;
      d["batches_invalid"] = c.invalid;
      d["env_steps"] = c.env_steps;
      py::list workers;
      for (const auto& [k, w] : in.workers()) {
        py::dict a;
        a["worker_id"] = wire_text(w.worker_id);
        a["session"] = w.session;
        a["received"] = w.received;
        a["lost"] = w.lost;
        a["duplicates"] = w.duplicates;
        a["invalid"] = w.invalid;
        a["env_steps"] = w.env_steps;
        workers.append(a);
      }
      d["workers"] = workers;
    });
    d["evaluation_answers_refused"] = answers_refused_;
    return d;
  }

  // The ids of this experiment's live workers (the learner's roster: heard within the config's
  // worker_timeout_seconds, not finished), once each.
  std::vector<std::string> worker_ids() {
    std::vector<std::string> out;
    for (const auto& w : roster_.workers())
      if (w.live && std::find(out.begin(), out.end(), w.view.last.worker_id()) == out.end())
        out.push_back(w.view.last.worker_id());
    return out;
  }
  py::list workers() {
    py::list out;
    for (const auto& id : worker_ids()) out.append(wire_text(id));
    return out;
  }

  // worker_id's latest live heartbeat: its session, and the participant that wrote it.
  std::pair<uint64_t, std::string> latest_of(const std::string& worker_id) {
    std::pair<uint64_t, std::string> out;
    double seen = -1;
    for (const auto& w : roster_.workers())
      if (w.live && w.view.last.worker_id() == worker_id && w.view.seen > seen) {
        seen = w.view.seen;
        out = {w.view.last.worker_session(), w.view.writer};
      }
    return out;
  }

  // Asks a worker (worker_id, else the first one heard) to run `episodes` episodes of the policy
  // (a dict as publish() takes) on evaluation envs of its own, and waits up to timeout seconds for
  // the answer, checked as farm-learner checks one. Returns its returns, lengths and flags.
  py::dict evaluate(const py::dict& policy, int episodes, std::string worker_id, uint64_t seed, double timeout) {
    const int most = std::max(cfg_.eval().episodes(), cfg_.eval().final_episodes());
    if (episodes < 1 || episodes > most)
      throw py::value_error("episodes: expected 1.." + std::to_string(most) +
                            " (the config's eval.episodes / final_episodes), got " + std::to_string(episodes));
    const farm::PolicyParams pp = params_of(policy);
    const std::vector<std::string> live = worker_ids();
    if (worker_id.empty()) {
      if (live.empty()) throw std::runtime_error("no worker of experiment '" + cfg_.experiment_id() + "' is heard");
      worker_id = live.front();
    } else if (std::find(live.begin(), live.end(), worker_id) == live.end()) {
      throw std::runtime_error("worker '" + worker_id + "' is not heard");
    }
    farm::msg::EvaluationRequest q;
    q.experiment_id(cfg_.experiment_id());
    q.learner_session(eval_session_);
    q.request_id(++request_id_);
    q.worker_id(worker_id);
    q.policy_version(pp.version);
    q.episodes(uint32_t(episodes));
    q.seed(seed);
    farm::dds::to_wire(pp, cfg_.experiment_id(), q.policy());
    q.first_episode(0);
    farm::EvalExpected e;
    e.experiment_id = cfg_.experiment_id();
    e.learner_session = eval_session_;
    e.worker_id = worker_id;
    e.request_id = q.request_id();
    const auto [session, writer] = latest_of(worker_id);
    e.worker_session = session;
    e.policy_version = pp.version;
    e.episodes = episodes;
    e.num_metrics = int(task_.metric_names.size());
    e.max_episode_steps = task_.max_episode_steps;
    e.reward_bound = task_.reward_bound;
    e.reward_min = task_.reward_min;
    e.reward_max = task_.reward_max;
    farm::msg::EvaluationAnswer a;
    std::string why;
    bool got = false;
    {
      py::gil_scoped_release nogil;
      // The writer's history is full only while workers have not taken earlier requests.
      for (int tries = 0; !eval_out_.write(q); ++tries)
        if (tries == 3) {
          why = "the request could not be written (earlier requests not yet taken by the workers)";
          got = true;
          break;
        }
      for (const double end = farm::now_seconds() + timeout; !got && farm::now_seconds() < end;) {
        eprosima::fastdds::dds::SampleInfo info;
        if (!eval_in_.take(a, info)) {
          eval_in_.wait(0.05);
          continue;
        }
        if (a.learner_session() != eval_session_ || a.request_id() != q.request_id()) continue;
        // Every field of the request can be read off the bus: only the participant whose heartbeats
        // put the worker in the roster answers for it (as farm-learner's Evaluator takes answers).
        const auto& from = info.sample_identity.writer_guid();
        if ((!writer.empty() && farm::dds::participant_key(from) != writer) ||
            (!bus_.security_dir().empty() && bus_.authenticated_name(from) != worker_id)) {
          ++answers_refused_;
          continue;
        }
        why = a.error().empty() ? farm::check_eval_answer(a, e) : "the worker says: " + a.error();
        got = true;
      }
    }
    if (!got) {
      const std::string msg = "evaluation " + std::to_string(q.request_id()) + " of worker '" + worker_id +
                              "' not answered within " + farm::config_checks::num(timeout) + " s";
      PyErr_SetString(PyExc_TimeoutError, msg.c_str());
      throw py::error_already_set();
    }
    if (!why.empty()) throw std::runtime_error("evaluation " + std::to_string(q.request_id()) + " refused: " + why);
    std::vector<float> returns;
    std::vector<int> lengths;
    for (const auto& ep : a.episodes()) {
      returns.push_back(ep.episode_return());
      lengths.push_back(int(ep.length()));
    }
    py::dict d;
    d["worker_id"] = worker_id;
    d["policy_version"] = pp.version;
    d["returns"] = array_of(returns, {py::ssize_t(returns.size())});
    d["lengths"] = array_of(lengths, {py::ssize_t(lengths.size())});
    d["seconds"] = a.seconds();
    return d;
  }

  // Tells the workers the experiment has finished (they end); idempotent.
  void finish() {
    if (finished_) return;
    finished_ = true;
    spec_.publish(true);
  }

 private:
  farm::config::ExperimentConfig cfg_;
  farm::robots::TaskSpec task_;
  farm::dds::Bus bus_;
  farm::EventLog events_;
  farm::SpecPublisher spec_;
  farm::WeightPublisher weights_;
  farm::IngestThread intake_;
  farm::RosterThread roster_;
  farm::dds::Writer<farm::msg::EvaluationRequest, farm::msg::EvaluationRequestPubSubType> eval_out_;
  farm::dds::Reader<farm::msg::EvaluationAnswer, farm::msg::EvaluationAnswerPubSubType> eval_in_;
  uint64_t eval_session_ = farm::dds::random_session_id(), request_id_ = 0;
  uint64_t answers_refused_ = 0;  // evaluation answers from another participant than the worker asked
  uint64_t version_ = 0;
  bool finished_ = false;
};

}  // namespace

void add_learner_bus(py::module_& m) {
  py::class_<LearnerBus>(m, "LearnerBus")
      .def(py::init<const std::string&, int, const std::string&, const std::string&>(), py::arg("config"),
           py::arg("domain") = 0, py::arg("profiles") = "", py::arg("events") = "")
      .def_property_readonly("obs_dim", &LearnerBus::obs_dim)
      .def_property_readonly("act_dim", &LearnerBus::act_dim)
      .def_property_readonly("num_actions", &LearnerBus::num_actions)
      .def_property_readonly("experiment_id", &LearnerBus::experiment_id)
      .def_property_readonly("domain", &LearnerBus::domain)
      .def("take", &LearnerBus::take, py::arg("max_batches") = 256, py::arg("timeout") = 0.1)
      .def("publish", &LearnerBus::publish, py::arg("policy"))
      .def("counters", &LearnerBus::counters)
      .def("workers", &LearnerBus::workers)
      .def("evaluate", &LearnerBus::evaluate, py::arg("policy"), py::arg("episodes"), py::arg("worker_id") = "",
           py::arg("seed") = 0, py::arg("timeout") = 60.0)
      .def("finish", &LearnerBus::finish);
}
