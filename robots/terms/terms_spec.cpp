#include "terms_spec.h"

#include <map>
#include <regex>
#include <stdexcept>

namespace farm::robots::terms {

const std::vector<TermInfo>& observation_terms() {
  static const std::vector<TermInfo> t = {
#define OBS(name, names, size, params) {#name, Names::names, size, params},
#include "terms_catalogue.def"
#undef OBS
  };
  return t;
}

const std::vector<TermInfo>& reward_terms() {
  static const std::vector<TermInfo> t = {
#define REWARD(name, names, params) {#name, Names::names, 0, params},
#include "terms_catalogue.def"
#undef REWARD
  };
  return t;
}

const std::vector<TermInfo>& termination_terms() {
  static const std::vector<TermInfo> t = {
#define TERMINATION(name, names, params) {#name, Names::names, 0, params},
#include "terms_catalogue.def"
#undef TERMINATION
  };
  return t;
}

namespace {

const TermInfo& find(const std::vector<TermInfo>& list, const std::string& name) {
  for (const auto& t : list)
    if (name == t.name) return t;
  std::string known;
  for (const auto& t : list) known += (known.empty() ? "" : ", ") + std::string(t.name);
  throw std::invalid_argument("unknown term '" + name + "'; known: " + known);
}

std::string list(const std::vector<std::string>& names) {
  std::string s;
  for (const auto& n : names) s += (s.empty() ? "" : ", ") + (n.empty() ? std::string("(unnamed)") : n);
  return s.empty() ? "none" : s;
}

// The candidates a kind selects from, as (id, name).
std::vector<std::pair<int, std::string>> candidates(Names kind, const ModelInfo& m) {
  std::vector<std::pair<int, std::string>> c;
  switch (kind) {
    case Names::Joints:
      for (size_t j = 0; j < m.joints.size(); ++j)
        if (m.joints[j].type == "hinge" || m.joints[j].type == "slide") c.emplace_back(int(j), m.joints[j].name);
      break;
    case Names::Bodies:
    case Names::BodiesRequired:
    case Names::AllBodies:
    case Names::Contacts:
    case Names::ContactsRequired:
      for (size_t b = 1; b < m.bodies.size(); ++b) c.emplace_back(int(b), m.bodies[b]);
      break;
    case Names::Geoms:
      for (size_t g = 0; g < m.geoms.size(); ++g) c.emplace_back(int(g), m.geoms[g]);
      break;
    case Names::Sensors:
      for (size_t s = 0; s < m.sensors.size(); ++s) c.emplace_back(int(s), m.sensors[s].name);
      break;
    case Names::None:
      break;
  }
  return c;
}

const char* kind_name(Names k) {
  switch (k) {
    case Names::Joints:
      return "hinge or slide joint";
    case Names::Bodies:
    case Names::BodiesRequired:
    case Names::AllBodies:
    case Names::Contacts:
    case Names::ContactsRequired:
      return "body";
    case Names::Geoms:
      return "geom";
    case Names::Sensors:
      return "sensor";
    case Names::None:
      break;
  }
  return "item";
}

}  // namespace

std::vector<int> select(Names kind, const google::protobuf::RepeatedPtrField<std::string>& names,
                        const ModelInfo& model, int root) {
  const auto cands = candidates(kind, model);
  std::vector<int> ids;
  if (names.empty()) {
    if (kind == Names::Bodies || kind == Names::Contacts) return {root};
    if (kind == Names::AllBodies) {
      for (size_t b = 0; b < model.bodies.size(); ++b) ids.push_back(int(b));  // the world included
      return ids;
    }
    if (kind == Names::BodiesRequired) throw std::invalid_argument("names: expected at least one body name");
    if (kind == Names::ContactsRequired)
      throw std::invalid_argument("names: expected at least one body name (or geoms: geom names)");
    for (const auto& [id, n] : cands) ids.push_back(id);
    return ids;
  }
  std::vector<std::string> all;
  for (const auto& [id, n] : cands) all.push_back(n);
  for (const std::string& entry : names) {
    std::regex re;
    try {
      re = std::regex(entry, std::regex::ECMAScript);
    } catch (const std::regex_error& e) {
      throw std::invalid_argument("names: '" + entry + "' is neither a name nor a regular expression (" + e.what() +
                                  ")");
    }
    bool any = false;
    for (const auto& [id, n] : cands) {
      if (n == entry || (!n.empty() && std::regex_match(n, re))) {
        any = true;
        if (std::find(ids.begin(), ids.end(), id) == ids.end()) ids.push_back(id);
      }
    }
    if (!any)
      throw std::invalid_argument("names: '" + entry + "' matches no " + kind_name(kind) +
                                  " of the model; there are: " + list(all));
  }
  return ids;
}

std::vector<int> contact_items(Names kind, const google::protobuf::RepeatedPtrField<std::string>& names,
                               const google::protobuf::RepeatedPtrField<std::string>& geoms, const ModelInfo& model,
                               int root, bool* by_geom) {
  if (by_geom) *by_geom = !geoms.empty();
  if (geoms.empty()) return select(kind, names, model, root);
  if (!names.empty()) throw std::invalid_argument("names: a contact term reads bodies (names) or geoms, not both");
  return select(Names::Geoms, geoms, model, root);
}

int root_body(const config::TermsConfig& cfg, const ModelInfo& model) {
  if (cfg.root_body().empty()) {
    if (model.bodies.size() < 2) throw std::invalid_argument("root_body: the model has no body below the world");
    return 1;
  }
  for (size_t b = 1; b < model.bodies.size(); ++b)
    if (model.bodies[b] == cfg.root_body()) return int(b);
  std::vector<std::string> all(model.bodies.begin() + 1, model.bodies.end());
  throw std::invalid_argument("root_body: '" + cfg.root_body() + "' is no body of the model; there are: " + list(all));
}

std::vector<int> action_targets(const config::TermsConfig& cfg, const ModelInfo& model) {
  const auto& a = cfg.action();
  if (a.type() == "position") {
    const std::vector<int> joints = select(Names::Joints, a.names(), model, 0);
    for (int j : joints) {
      bool driven = false;
      for (const auto& aj : model.actuator_joints) driven = driven || aj == model.joints[j].name;
      if (!driven || model.joints[j].name.empty())
        throw std::invalid_argument("names: joint '" + model.joints[j].name +
                                    "' has no actuator (a <motor joint=...>) for the PD law's torque");
    }
    return joints;
  }
  if (a.type() == "actuator") {
    std::vector<int> ids;
    if (a.names().empty()) {
      for (size_t i = 0; i < model.actuators.size(); ++i) ids.push_back(int(i));
    } else {
      for (const std::string& entry : a.names()) {
        const std::regex re(entry, std::regex::ECMAScript);
        bool any = false;
        for (size_t i = 0; i < model.actuators.size(); ++i)
          if (model.actuators[i] == entry ||
              (!model.actuators[i].empty() && std::regex_match(model.actuators[i], re))) {
            any = true;
            if (std::find(ids.begin(), ids.end(), int(i)) == ids.end()) ids.push_back(int(i));
          }
        if (!any)
          throw std::invalid_argument("names: '" + entry +
                                      "' matches no actuator of the model; there are: " + list(model.actuators));
      }
    }
    if (ids.empty()) throw std::invalid_argument("names: the model has no actuator to drive");
    return ids;
  }
  throw std::invalid_argument("type: expected \"actuator\" or \"position\", got \"" + a.type() + "\"");
}

int observation_size(const config::ObsTerm& term, const ModelInfo& model, int root, int act_dim) {
  const TermInfo& info = find(observation_terms(), term.term());
  switch (info.item_size) {
    case kQpos:
      return model.nq() - term.skip();
    case kQvel:
      return model.nv() - term.skip();
    case kActDim:
      return act_dim;
    case kSensorDim: {
      int n = 0;
      for (int s : select(info.names, term.names(), model, root)) n += model.sensors[s].dim;
      return n;
    }
    default:
      if (info.names == Names::None) return info.item_size;
      if (info.names == Names::Contacts)
        return info.item_size * int(contact_items(info.names, term.names(), term.geoms(), model, root).size());
      return info.item_size * int(select(info.names, term.names(), model, root).size());
  }
}

std::vector<std::string> expression_quantities(const ModelInfo& model) {
  std::vector<std::string> q = {"x_vel",     "y_vel",      "z_vel",    "progress_x", "height",    "up_z",
                                "roll_rate", "pitch_rate", "yaw_rate", "action_sq",  "torque_sq", "cmd_x",
                                "cmd_y",     "cmd_yaw",    "step",     "time"};
  for (const auto& s : model.sensors) {
    if (s.name.empty()) continue;
    std::string id;
    for (char c : s.name) id += std::isalnum(static_cast<unsigned char>(c)) ? c : '_';
    if (s.dim == 1) {
      q.push_back(id);
    } else {
      for (int i = 0; i < s.dim; ++i) q.push_back(id + "_" + std::to_string(i));
    }
  }
  return q;
}

std::vector<std::string> metric_names(const config::TermsConfig& cfg) {
  std::vector<std::string> m = {"distance_x", "terminated", "time_s"}, ids;
  std::map<std::string, int> seen;
  for (const auto& r : cfg.reward()) {
    const int k = seen[r.term()]++;
    ids.push_back(r.term() + (k ? "_" + std::to_string(k + 1) : ""));
  }
  for (const auto& id : ids) m.push_back("reward." + id);
  for (const auto& id : ids) m.push_back("mean." + id);
  return m;
}

TaskSpec terms_spec(const config::TaskConfig& cfg) { return task_spec(cfg.terms()); }

TaskSpec task_spec(const config::TermsConfig& cfg) {
  const ModelInfo model = scan_model(cfg);
  const int root = root_body(cfg, model);
  TaskSpec s;
  s.name = "terms";
  s.act_dim = int(action_targets(cfg, model).size());
  for (const auto& o : cfg.observation()) s.obs_dim += observation_size(o, model, root, s.act_dim);
  s.max_episode_steps = cfg.max_episode_steps();
  s.metric_names = metric_names(cfg);
  return s;
}

}  // namespace farm::robots::terms
