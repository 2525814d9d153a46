// The config checks of task.terms: every term name, parameter and model name, named by FILE:LINE:COL
// through the loader's Section (common/config_validator.h).
#include "terms_check.h"

#include <muParser.h>

#include <set>
#include <sstream>

#include "config_validator.h"
#include "terms_spec.h"

namespace farm::robots::terms {

namespace {

namespace pb = google::protobuf;
using config_checks::num;
using config_checks::Section;

std::set<std::string> words(const char* s) {
  std::set<std::string> w;
  std::stringstream ss(s);
  std::string x;
  while (ss >> x) w.insert(x);
  return w;
}

// The entry's term is in the list, and it sets no parameter the term does not read.
const TermInfo& check_term(const Section& s, const pb::Message& entry, const std::string& term,
                           const std::vector<TermInfo>& list, const std::set<std::string>& always) {
  const TermInfo* info = nullptr;
  for (const auto& t : list)
    if (term == t.name) info = &t;
  if (!info) {
    std::string known;
    for (const auto& t : list) known += (known.empty() ? "" : ", ") + std::string(t.name);
    s.fail("term", term.empty() ? "required; one of: " + known : "unknown term '" + term + "'; known: " + known);
  }
  const std::set<std::string> reads = words(info->params);
  std::vector<const pb::FieldDescriptor*> set;
  entry.GetReflection()->ListFields(entry, &set);
  for (const auto* f : set) {
    if (f->name() == "term" || always.count(f->name()) || reads.count(f->name())) continue;
    s.fail(f->name(), "term '" + term + "' does not read '" + f->name() + "'" +
                          (reads.empty() ? "" : " (it reads: " + std::string(info->params) + ")"));
  }
  return *info;
}

// select(), with its error placed at the `names` entry (or the section when names is empty).
void check_names(const Section& s, Names kind, const pb::RepeatedPtrField<std::string>& names, const ModelInfo& m,
                 int root, const char* field = "names") {
  for (int i = 0; i < names.size(); ++i) {
    pb::RepeatedPtrField<std::string> one;
    *one.Add() = names.Get(i);
    try {
      select(kind, one, m, root);
    } catch (const std::invalid_argument& e) {
      s.fail(field, e.what(), i);
    }
  }
  try {
    select(kind, names, m, root);
  } catch (const std::invalid_argument& e) {
    s.fail(field, e.what());
  }
}

// The items a term reads: its names, or for a contact term its names or geoms, and the geoms of
// `other`.
template <typename Entry>
void check_items(const Section& s, Names kind, const Entry& e, const ModelInfo& m, int root) {
  if (kind == Names::None) return;
  if (kind != Names::Contacts && kind != Names::ContactsRequired) return check_names(s, kind, e.names(), m, root);
  if (!e.geoms().empty()) {
    s.check(e.names().empty(), "geoms", "a contact term reads bodies (names) or geoms, not both");
    check_names(s, Names::Geoms, e.geoms(), m, root, "geoms");
  } else {
    check_names(s, kind, e.names(), m, root);
  }
  if (!e.other().empty()) check_names(s, Names::Geoms, e.other(), m, root, "other");
}

void check_expression(const Section& s, const std::string& expr, const ModelInfo& m) {
  if (expr.empty()) s.fail("expression", "required for term 'expression': a formula over named quantities");
  mu::Parser p;
  std::vector<double> vars(expression_quantities(m).size(), 0.0);
  const auto names = expression_quantities(m);
  for (size_t i = 0; i < names.size(); ++i) p.DefineVar(names[i], &vars[i]);
  try {
    p.SetExpr(expr);
    p.Eval();
  } catch (const mu::Parser::exception_type& e) {
    std::string known;
    for (const auto& n : names) known += (known.empty() ? "" : ", ") + n;
    s.fail("expression", "muparser: " + e.GetMsg() + " in \"" + expr + "\"; quantities: " + known);
  }
}

}  // namespace

void check_terms(const Section& task, const config::TaskConfig& t) {
  check_terms(task.nest("terms", t.terms()), t.terms());
}

void check_terms(const Section& s, const config::TermsConfig& c) {
  s.check(c.max_model_bytes() > 0 && c.max_model_bytes() <= kMaxModelBytesCap, "max_model_bytes",
          "expected 1.." + std::to_string(kMaxModelBytesCap) + ", got " + num(double(c.max_model_bytes())));
  s.check(c.physics_dt() >= 0 && c.physics_dt() <= 0.05, "physics_dt",
          "expected in [0, 0.05] (0: the model's timestep), got " + num(c.physics_dt()));
  s.check(c.control_substeps() >= 1 && c.control_substeps() <= 1000, "control_substeps",
          "expected 1..1000, got " + num(c.control_substeps()));
  s.at_least("max_episode_steps", c.max_episode_steps(), 1);
  try {
    check_bundle(c);
  } catch (const ModelError& e) {
    const bool files = std::string(e.what()).rfind("task.terms.model_files", 0) == 0;
    s.fail(files ? "model_files" : "model", e.what());
  }
  ModelInfo m;
  try {
    m = scan_model(c);
  } catch (const ModelError& e) {
    s.fail("model", e.what());
  }
  int root = 0;
  try {
    root = root_body(c, m);
  } catch (const std::invalid_argument& e) {
    s.fail("root_body", e.what());
  }

  const Section a = s.nest("action", c.action());
  const auto& act = c.action();
  a.check(act.type() == "actuator" || act.type() == "position", "type",
          "expected \"actuator\" or \"position\", got \"" + act.type() + "\"");
  int act_dim = 0;
  try {
    act_dim = int(action_targets(c, m).size());
  } catch (const std::invalid_argument& e) {
    a.fail("names", e.what());
  }
  a.finite_positive("scale", act.scale());
  a.finite_non_negative("kp", act.kp());
  a.finite_non_negative("kd", act.kd());
  a.finite_non_negative("torque_limit", act.torque_limit());
  a.check(act.velocity_limit() > 0, "velocity_limit", "expected > 0 (rad/s), got " + num(act.velocity_limit()));
  if (act.type() == "position" && act.default_pose_size() > 0 && act.default_pose_size() != act_dim)
    a.fail("default_pose",
           "expected one value per driven joint (" + num(act_dim) + "), got " + num(act.default_pose_size()));
  if (act.has_keyframe()) {
    bool found = false;
    for (const auto& k : m.keyframes) found = found || k == act.keyframe();
    a.check(found, "keyframe", "'" + act.keyframe() + "' is no keyframe of the model");
  }

  s.check(c.observation_size() > 0, "observation", "expected at least one observation term");
  const std::set<std::string> obs_always = {"scale", "offset", "clip", "noise"};
  for (int i = 0; i < c.observation_size(); ++i) {
    const auto& o = c.observation(i);
    const Section os = s.nest_at("observation", i, o);
    const TermInfo& info = check_term(os, o, o.term(), observation_terms(), obs_always);
    check_items(os, info.names, o, m, root);
    os.check(o.frame() == "local" || o.frame() == "world", "frame",
             "expected \"local\" or \"world\", got \"" + o.frame() + "\"");
    os.finite("scale", o.scale());
    os.finite("offset", o.offset());
    os.check(o.clip() > 0, "clip", "expected > 0, got " + num(o.clip()));
    os.finite_non_negative("noise", o.noise());
    const int limit = info.item_size == kQpos ? m.nq() : info.item_size == kQvel ? m.nv() : 0;
    os.check(o.skip() >= 0 && o.skip() <= limit, "skip",
             "expected 0.." + num(limit) + " (the model's " + (info.item_size == kQvel ? "nv" : "nq") + "), got " +
                 num(o.skip()));
  }
  for (int i = 0; i < c.reward_size(); ++i) {
    const auto& r = c.reward(i);
    const Section rs = s.nest_at("reward", i, r);
    const TermInfo& info = check_term(rs, r, r.term(), reward_terms(), {"weight"});
    check_items(rs, info.names, r, m, root);
    rs.finite("weight", r.weight());
    rs.check(r.axis() >= 0 && r.axis() <= 2, "axis", "expected 0 (x), 1 (y) or 2 (z), got " + num(r.axis()));
    rs.check(r.frame() == "local" || r.frame() == "world", "frame",
             "expected \"local\" or \"world\", got \"" + r.frame() + "\"");
    rs.finite_positive("sigma", r.sigma());
    rs.finite_non_negative("threshold", r.threshold());
    rs.finite("target", r.target());
    if (r.term() == "joint_limits")
      rs.check(
          r.target() > 0 && r.target() <= 1, "target",
          "term 'joint_limits': the share of each joint's range before the penalty, in (0, 1]; got " + num(r.target()));
    if (r.term() == "expression") check_expression(rs, r.expression(), m);
  }
  for (int i = 0; i < c.termination_size(); ++i) {
    const auto& t = c.termination(i);
    const Section ts = s.nest_at("termination", i, t);
    const TermInfo& info = check_term(ts, t, t.term(), termination_terms(), {});
    check_items(ts, info.names, t, m, root);
    ts.check(!(t.min() > t.max()), "min", "expected <= max (" + num(t.max()) + "), got " + num(t.min()));
    ts.check(t.skip() >= 0 && t.skip() <= m.nq() + m.nv(), "skip",
             "expected 0.." + num(m.nq() + m.nv()) + " (the model's nq + nv), got " + num(t.skip()));
  }
  const Section rs = s.nest("reset", c.reset());
  const auto& r = c.reset();
  rs.finite_non_negative("qpos_noise", r.qpos_noise());
  rs.finite_non_negative("qvel_noise", r.qvel_noise());
  rs.check(r.friction_min() > 0 && r.friction_min() <= r.friction_max() && std::isfinite(r.friction_max()),
           "friction_min",
           "expected 0 < friction_min <= friction_max (" + num(r.friction_max()) + "), got " + num(r.friction_min()));
  rs.check(r.mass_min() > 0 && r.mass_min() <= r.mass_max() && std::isfinite(r.mass_max()), "mass_min",
           "expected 0 < mass_min <= mass_max (" + num(r.mass_max()) + "), got " + num(r.mass_min()));
  rs.check(r.joint_pos_scale_min() <= r.joint_pos_scale_max() && std::isfinite(r.joint_pos_scale_min()) &&
               std::isfinite(r.joint_pos_scale_max()),
           "joint_pos_scale_min",
           "expected finite, at most joint_pos_scale_max (" + num(r.joint_pos_scale_max()) + "), got " +
               num(r.joint_pos_scale_min()));
  if (!r.friction_geoms().empty()) check_names(rs, Names::Geoms, r.friction_geoms(), m, root, "friction_geoms");
  if (!r.clear_geoms().empty()) check_names(rs, Names::Geoms, r.clear_geoms(), m, root, "clear_geoms");
  rs.finite_non_negative("clearance", r.clearance());
  rs.finite_non_negative("root_vel_noise", r.root_vel_noise());
  rs.finite_non_negative("push_interval_s", r.push_interval_s());
  rs.finite_non_negative("push_max_vel", r.push_max_vel());
  const Section cs = s.nest("command", c.command());
  const auto& k = c.command();
  cs.check(k.lin_vel_x_min() <= k.lin_vel_x_max(), "lin_vel_x_min", "expected <= lin_vel_x_max");
  cs.check(k.lin_vel_y_min() <= k.lin_vel_y_max(), "lin_vel_y_min", "expected <= lin_vel_y_max");
  cs.check(k.yaw_rate_min() <= k.yaw_rate_max(), "yaw_rate_min", "expected <= yaw_rate_max");
  cs.check(k.resample_prob() >= 0 && k.resample_prob() <= 1, "resample_prob",
           "expected in [0, 1], got " + num(k.resample_prob()));
  cs.finite_non_negative("small_command", k.small_command());
  cs.finite_non_negative("heading_gain", k.heading_gain());
  s.check(c.max_qvel() > 0, "max_qvel", "expected > 0 (rad/s or m/s), got " + num(c.max_qvel()));
}

}  // namespace farm::robots::terms
