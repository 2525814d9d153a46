#include "config.h"

#include <google/protobuf/io/tokenizer.h>
#include <google/protobuf/text_format.h>

#include <cmath>
#include <fstream>
#include <functional>
#include <sstream>

namespace farm {

namespace pb = google::protobuf;

namespace {

class Collector : public pb::io::ErrorCollector {
 public:
  explicit Collector(std::string source) : source_(std::move(source)) {}
  void AddError(int line, pb::io::ColumnNumber column, const std::string& message) override {
    if (!first_.empty()) return;
    first_ = source_ + ":" + std::to_string(line + 1) + ":" + std::to_string(column + 1) + ": " +
             message;
  }
  void AddWarning(int, pb::io::ColumnNumber, const std::string&) override {}
  const std::string& first() const { return first_; }

 private:
  std::string source_;
  std::string first_;
};

// Walks the parsed message with the parser's location tree so a range error can name the line
// where the offending value was written.
class Validator {
 public:
  Validator(std::string source, const pb::TextFormat::ParseInfoTree* tree)
      : source_(std::move(source)), tree_(tree) {}

  void fail(const pb::Message& msg, const std::string& field, const std::string& path,
            const std::string& what) const {
    std::string where = source_;
    const pb::FieldDescriptor* fd = msg.GetDescriptor()->FindFieldByName(field);
    const pb::TextFormat::ParseInfoTree* t = tree_for(msg);
    if (fd && t) {
      auto loc = t->GetLocation(fd, fd->is_repeated() ? 0 : -1);
      if (loc.line >= 0) where += ":" + std::to_string(loc.line + 1) + ":" + std::to_string(loc.column + 1);
    }
    throw ConfigError(where + ": field '" + path + "': " + what);
  }

  // Location trees of nested messages, found by identity of the message object.
  void nest(const pb::Message& parent, const std::string& field, const pb::Message& child) {
    const pb::TextFormat::ParseInfoTree* t = tree_for(parent);
    const pb::FieldDescriptor* fd = parent.GetDescriptor()->FindFieldByName(field);
    trees_.push_back({&child, t && fd ? t->GetTreeForNested(fd, -1) : nullptr});
  }

 private:
  const pb::TextFormat::ParseInfoTree* tree_for(const pb::Message& m) const {
    for (auto& [msg, t] : trees_) if (msg == &m) return t;
    return tree_;  // the root
  }
  std::string source_;
  const pb::TextFormat::ParseInfoTree* tree_;
  std::vector<std::pair<const pb::Message*, const pb::TextFormat::ParseInfoTree*>> trees_;
};

std::string num(double v) {
  std::ostringstream o;
  o << v;
  return o.str();
}

void validate(const config::ExperimentConfig& c, Validator& v) {
  auto positive = [&](const pb::Message& m, const std::string& f, const std::string& path, double x) {
    if (!(x > 0)) v.fail(m, f, path, "expected > 0, got " + num(x));
  };
  auto in_unit = [&](const pb::Message& m, const std::string& f, const std::string& path, double x) {
    if (!(x > 0 && x <= 1)) v.fail(m, f, path, "expected in (0, 1], got " + num(x));
  };

  if (!c.has_experiment_id() || c.experiment_id().empty())
    v.fail(c, "experiment_id", "experiment_id", "required: a name for the run, e.g. \"pendulum_sac\"");
  for (char ch : c.experiment_id()) {
    if (!(std::isalnum(static_cast<unsigned char>(ch)) || ch == '_' || ch == '-' || ch == '.'))
      v.fail(c, "experiment_id", "experiment_id",
             "expected letters, digits, '_', '-' or '.', got \"" + c.experiment_id() + "\"");
  }
  // It names the run folder (<run_root>/<experiment_id>): "." and ".." would name another one.
  if (c.experiment_id() == "." || c.experiment_id() == "..")
    v.fail(c, "experiment_id", "experiment_id", "\"" + c.experiment_id() + "\" is not a name for a run folder");
  if (c.algorithm() != "sac" && c.algorithm() != "ppo" && c.algorithm() != "dqn")
    v.fail(c, "algorithm", "algorithm", "expected one of: sac, ppo, dqn; got \"" + c.algorithm() + "\"");

  v.nest(c, "task", c.task());
  const auto& p = c.task().pendulum();
  v.nest(c.task(), "pendulum", p);
  positive(p, "dt", "task.pendulum.dt", p.dt());
  positive(p, "mass", "task.pendulum.mass", p.mass());
  positive(p, "length", "task.pendulum.length", p.length());
  positive(p, "max_speed", "task.pendulum.max_speed", p.max_speed());
  positive(p, "max_torque", "task.pendulum.max_torque", p.max_torque());
  positive(p, "max_episode_steps", "task.pendulum.max_episode_steps", p.max_episode_steps());
  if (p.init_max_speed() < 0) v.fail(p, "init_max_speed", "task.pendulum.init_max_speed", "expected >= 0, got " + num(p.init_max_speed()));

  const auto& s = c.sac();
  v.nest(c, "sac", s);
  positive(s, "actor_lr", "sac.actor_lr", s.actor_lr());
  positive(s, "critic_lr", "sac.critic_lr", s.critic_lr());
  positive(s, "alpha_lr", "sac.alpha_lr", s.alpha_lr());
  in_unit(s, "gamma", "sac.gamma", s.gamma());
  in_unit(s, "tau", "sac.tau", s.tau());
  positive(s, "batch_size", "sac.batch_size", s.batch_size());
  if (s.buffer_size() < s.batch_size())
    v.fail(s, "buffer_size", "sac.buffer_size", "expected >= sac.batch_size (" + num(s.batch_size()) + "), got " + num(s.buffer_size()));
  if (s.learning_starts() < 0) v.fail(s, "learning_starts", "sac.learning_starts", "expected >= 0, got " + num(s.learning_starts()));
  for (int h : s.hidden()) if (h <= 0) v.fail(s, "hidden", "sac.hidden", "expected sizes > 0, got " + num(h));
  for (int h : s.critic_hidden())
    if (h <= 0) v.fail(s, "critic_hidden", "sac.critic_hidden", "expected sizes > 0, got " + num(h));
  positive(s, "initial_alpha", "sac.initial_alpha", s.initial_alpha());
  if (!(s.log_std_min() < s.log_std_max()))
    v.fail(s, "log_std_min", "sac.log_std_min", "expected < sac.log_std_max");
  positive(s, "max_updates_per_step", "sac.max_updates_per_step", s.max_updates_per_step());
  positive(s, "publish_every_updates", "sac.publish_every_updates", s.publish_every_updates());
  if (!valid_device_name(s.device()))
    v.fail(s, "device", "sac.device", "expected \"cpu\", \"cuda\" or \"cuda:N\", got \"" + s.device() + "\"");
  if (s.activation() != "relu" && s.activation() != "tanh")
    v.fail(s, "activation", "sac.activation", "expected \"relu\" or \"tanh\", got \"" + s.activation() + "\"");

  if (c.algorithm() == "dqn") {
    const auto& d = c.dqn();
    v.nest(c, "dqn", d);
    positive(d, "learning_rate", "dqn.learning_rate", d.learning_rate());
    positive(d, "batch_size", "dqn.batch_size", d.batch_size());
    if (d.buffer_size() < d.batch_size())
      v.fail(d, "buffer_size", "dqn.buffer_size", "expected >= dqn.batch_size (" + num(d.batch_size()) + "), got " + num(d.buffer_size()));
    in_unit(d, "gamma", "dqn.gamma", d.gamma());
    in_unit(d, "exploration_fraction", "dqn.exploration_fraction", d.exploration_fraction());
    in_unit(d, "exploration_initial_eps", "dqn.exploration_initial_eps", d.exploration_initial_eps());
    in_unit(d, "exploration_final_eps", "dqn.exploration_final_eps", d.exploration_final_eps());
    positive(d, "schedule_env_steps", "dqn.schedule_env_steps", d.schedule_env_steps());
    if (d.learning_starts() < 0) v.fail(d, "learning_starts", "dqn.learning_starts", "expected >= 0, got " + num(d.learning_starts()));
    positive(d, "target_update_updates", "dqn.target_update_updates", d.target_update_updates());
    positive(d, "max_grad_norm", "dqn.max_grad_norm", d.max_grad_norm());
    for (int h : d.hidden()) if (h <= 0) v.fail(d, "hidden", "dqn.hidden", "expected sizes > 0, got " + num(h));
    positive(d, "max_updates_per_step", "dqn.max_updates_per_step", d.max_updates_per_step());
    positive(d, "publish_every_updates", "dqn.publish_every_updates", d.publish_every_updates());
  }

  if (c.algorithm() == "ppo") {
    const auto& pp = c.ppo();
    v.nest(c, "ppo", pp);
    if (pp.variant() != "clip_kl" && pp.variant() != "plain")
      v.fail(pp, "variant", "ppo.variant", "expected \"clip_kl\" or \"plain\", got \"" + pp.variant() + "\"");
    if (pp.steps_per_fit() < 0 || pp.episodes_per_fit() < 0 || (pp.steps_per_fit() > 0) == (pp.episodes_per_fit() > 0))
      v.fail(pp, "episodes_per_fit", "ppo.episodes_per_fit",
             "set exactly one of ppo.steps_per_fit and ppo.episodes_per_fit > 0 (steps_per_fit: 0 to fit by episodes)");
    positive(pp, "mini_batch_size", "ppo.mini_batch_size", pp.mini_batch_size());
    positive(pp, "learning_rate", "ppo.learning_rate", pp.learning_rate());
    in_unit(pp, "gamma", "ppo.gamma", pp.gamma());
    if (!(pp.gae_lambda() >= 0 && pp.gae_lambda() <= 1)) v.fail(pp, "gae_lambda", "ppo.gae_lambda", "expected in [0, 1], got " + num(pp.gae_lambda()));
    positive(pp, "clip_epsilon", "ppo.clip_epsilon", pp.clip_epsilon());
    positive(pp, "epochs", "ppo.epochs", pp.epochs());
    positive(pp, "max_grad_norm", "ppo.max_grad_norm", pp.max_grad_norm());
    positive(pp, "desired_kl", "ppo.desired_kl", pp.desired_kl());
    if (pp.max_policy_lag() < 0) v.fail(pp, "max_policy_lag", "ppo.max_policy_lag", "expected >= 0, got " + num(pp.max_policy_lag()));
    if (pp.steps_per_run() < 0) v.fail(pp, "steps_per_run", "ppo.steps_per_run", "expected >= 0 (0 = no limit)");
    if (pp.episodes_per_run() < 0) v.fail(pp, "episodes_per_run", "ppo.episodes_per_run", "expected >= 0 (0 = no limit)");
  }

  const auto& e = c.eval();
  v.nest(c, "eval", e);
  positive(e, "episodes", "eval.episodes", e.episodes());
  positive(e, "every_seconds", "eval.every_seconds", e.every_seconds());
  positive(e, "final_episodes", "eval.final_episodes", e.final_episodes());

  const auto& st = c.stop();
  v.nest(c, "stop", st);
  if (st.max_seconds() < 0) v.fail(st, "max_seconds", "stop.max_seconds", "expected >= 0 (0 = no limit), got " + num(st.max_seconds()));
  if (st.max_env_steps() < 0) v.fail(st, "max_env_steps", "stop.max_env_steps", "expected >= 0 (0 = no limit)");
  if (st.max_updates() < 0) v.fail(st, "max_updates", "stop.max_updates", "expected >= 0 (0 = no limit)");

  const auto& w = c.worker();
  v.nest(c, "worker", w);
  if (!(w.envs_per_worker() > 0 && w.envs_per_worker() <= kMaxEnvsPerWorker))
    v.fail(w, "envs_per_worker", "worker.envs_per_worker",
           "expected 1.." + std::to_string(kMaxEnvsPerWorker) + ", got " + num(w.envs_per_worker()));
  if (!(w.steps_per_batch() > 0 && w.steps_per_batch() <= kMaxStepsPerBatch))
    v.fail(w, "steps_per_batch", "worker.steps_per_batch",
           "expected 1.." + std::to_string(kMaxStepsPerBatch) + ", got " + num(w.steps_per_batch()));
  positive(w, "max_batches_per_version", "worker.max_batches_per_version", w.max_batches_per_version());

  if (c.run_root().empty()) v.fail(c, "run_root", "run_root", "expected a directory path");
  positive(c, "checkpoint_every_seconds", "checkpoint_every_seconds", c.checkpoint_every_seconds());
  positive(c, "torch_threads", "torch_threads", c.torch_threads());
  positive(c, "log_every_seconds", "log_every_seconds", c.log_every_seconds());
  positive(c, "worker_timeout_seconds", "worker_timeout_seconds", c.worker_timeout_seconds());
}

}  // namespace

config::ExperimentConfig parse_config_text(const std::string& text, const std::string& source) {
  config::ExperimentConfig cfg;
  pb::TextFormat::Parser parser;
  Collector errors(source);
  pb::TextFormat::ParseInfoTree tree;
  parser.RecordErrorsTo(&errors);
  parser.WriteLocationsTo(&tree);
  if (!parser.ParseFromString(text, &cfg)) {
    throw ConfigError(errors.first().empty() ? source + ": cannot parse config" : errors.first());
  }
  Validator v(source, &tree);
  validate(cfg, v);
  return cfg;
}

namespace {

// Names of the fields that name a file to write; found at any depth of the config.
bool is_output_path(const pb::FieldDescriptor* f) { return f->name() == "hfield_png"; }

// Visits the set output-path fields under msg (path so far: prefix); clears them when asked.
void walk_output_paths(pb::Message* msg, const std::string& prefix, bool clear, std::vector<std::string>* found) {
  const pb::Reflection* r = msg->GetReflection();
  std::vector<const pb::FieldDescriptor*> fields;
  r->ListFields(*msg, &fields);
  for (const pb::FieldDescriptor* f : fields) {
    const std::string path = prefix + f->name();
    if (f->type() == pb::FieldDescriptor::TYPE_MESSAGE) {
      if (f->is_repeated()) {
        for (int i = 0; i < r->FieldSize(*msg, f); ++i)
          walk_output_paths(r->MutableRepeatedMessage(msg, f, i), path + "[" + std::to_string(i) + "].", clear, found);
      } else {
        walk_output_paths(r->MutableMessage(msg, f), path + ".", clear, found);
      }
    } else if (is_output_path(f)) {
      if (found) found->push_back(path);
      if (clear) r->ClearField(msg, f);
    }
  }
}

}  // namespace

std::vector<std::string> output_path_fields(const config::ExperimentConfig& cfg) {
  config::ExperimentConfig copy = cfg;
  std::vector<std::string> found;
  walk_output_paths(&copy, "", false, &found);
  return found;
}

void clear_output_paths(config::ExperimentConfig* cfg) { walk_output_paths(cfg, "", true, nullptr); }

config::ExperimentConfig parse_config_from_bus(const std::string& text, const std::string& source) {
  config::ExperimentConfig cfg = parse_config_text(text, source);
  const std::vector<std::string> paths = output_path_fields(cfg);
  if (!paths.empty())
    throw ConfigError(source + ": field '" + paths.front() +
                      "' names a file for this host to write; a config received over the bus may not");
  return cfg;
}

config::ExperimentConfig load_config_file(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw ConfigError(path + ": cannot open config file");
  std::stringstream ss;
  ss << in.rdbuf();
  return parse_config_text(ss.str(), path);
}

std::string config_to_text(const config::ExperimentConfig& cfg) {
  std::string out;
  pb::TextFormat::PrintToString(cfg, &out);
  return out;
}

bool valid_device_name(const std::string& name) {
  if (name == "cpu" || name == "cuda") return true;
  const std::string prefix = "cuda:";
  if (name.size() <= prefix.size() || name.compare(0, prefix.size(), prefix) != 0) return false;
  for (size_t i = prefix.size(); i < name.size(); ++i)
    if (name[i] < '0' || name[i] > '9') return false;
  return name.size() - prefix.size() <= 3;
}

std::vector<int> sac_hidden(const config::SacConfig& sac) {
  if (sac.hidden_size() == 0) return {256, 256};  // sb3 SAC net_arch (seed 001 §4.3.2)
  return {sac.hidden().begin(), sac.hidden().end()};
}

std::vector<int> sac_critic_hidden(const config::SacConfig& sac) {
  if (sac.critic_hidden_size() == 0) return sac_hidden(sac);
  return {sac.critic_hidden().begin(), sac.critic_hidden().end()};
}

}  // namespace farm
