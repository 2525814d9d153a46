#include "mjcf_bundle.h"

#include <tinyxml2.h>

#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <set>
#include <sstream>

namespace farm::robots::terms {

namespace x = tinyxml2;

namespace {

std::string base_name(const std::string& p) { return p.substr(p.find_last_of('/') + 1); }

// "a/./b/../c" -> "a/c"; an empty result or one that climbs out of the folder -> "".
std::string normalize(const std::string& path) {
  std::vector<std::string> parts;
  std::stringstream ss(path);
  std::string part;
  while (std::getline(ss, part, '/')) {
    if (part.empty() || part == ".") continue;
    if (part == "..") {
      if (parts.empty()) return "";
      parts.pop_back();
      continue;
    }
    parts.push_back(part);
  }
  std::string out;
  for (const auto& p : parts) out += (out.empty() ? "" : "/") + p;
  return out;
}

std::string join(const std::string& dir, const std::string& file) {
  if (dir.empty()) return file;
  return dir + "/" + file;
}

// Gives the text of a file of the model's folder by its path relative to the folder; `what`
// names the element that asks for it (for errors).
using FileSource = std::function<const std::string&(const std::string& rel, const std::string& what)>;

// Walks a model: its main file and what it includes, each file parsed once.
class ModelWalker {
 public:
  ModelWalker(std::string model, FileSource source) : model_(std::move(model)), source_(std::move(source)) {}

  const x::XMLElement* root() { return parse(model_, "the model file")->RootElement(); }

  // Calls f on each child element of `parent`, with the children of an <include>d file's
  // <mujoco> in place of the <include>.
  void children(const x::XMLElement* parent, const std::function<void(const x::XMLElement*)>& f, int depth = 0) {
    if (depth > 32) throw ModelError(model_ + ": includes nest deeper than 32 files");
    for (const x::XMLElement* e = parent->FirstChildElement(); e; e = e->NextSiblingElement()) {
      if (std::string(e->Name()) == "include") {
        const char* file = e->Attribute("file");
        if (!file) throw ModelError(model_ + ": an <include> without a file attribute");
        const std::string rel = resolve("", file, "<include file=\"" + std::string(file) + "\">");
        const x::XMLElement* inc = parse(rel, "<include file=\"" + std::string(file) + "\">")->RootElement();
        if (!inc || std::string(inc->Name()) != "mujoco")
          throw ModelError(model_ + ": included file '" + rel + "' has no <mujoco> root element");
        children(inc, f, depth + 1);
      } else {
        f(e);
      }
    }
  }

  // The path of `file` in the model's folder, as MuJoCo finds it (dir: the compiler's meshdir or
  // texturedir); throws when it is absolute or climbs out of the folder.
  std::string resolve(const std::string& dir, const std::string& file, const std::string& what) const {
    const std::string joined = join(dir, file);
    const std::string rel = normalize(joined);
    if (file.empty() || file[0] == '/' || !path_inside_folder(joined) || rel.empty())
      throw ModelError(model_ + ": " + what + " names '" + joined +
                       "', outside the model's folder (a model's files come from its own folder only)");
    return rel;
  }

  // The text of a file of the folder, through the source (it may throw).
  const std::string& file(const std::string& rel, const std::string& what) { return source_(rel, what); }

  const std::string& model() const { return model_; }

 private:
  x::XMLDocument* parse(const std::string& rel, const std::string& what) {
    auto it = docs_.find(rel);
    if (it != docs_.end()) return it->second.get();
    const std::string& text = source_(rel, what);
    auto doc = std::make_unique<x::XMLDocument>();
    if (doc->Parse(text.data(), text.size()) != x::XML_SUCCESS)
      throw ModelError(rel + ":" + std::to_string(doc->ErrorLineNum()) + ": " + doc->ErrorStr());
    return docs_.emplace(rel, std::move(doc)).first->second.get();
  }

  std::string model_;
  FileSource source_;
  std::map<std::string, std::unique_ptr<x::XMLDocument>> docs_;
};

// Every file the model names: its includes (by walking) and its assets.
void walk_files(ModelWalker& w) {
  const x::XMLElement* root = w.root();
  if (!root || std::string(root->Name()) != "mujoco")
    throw ModelError(w.model() + ": expected a <mujoco> root element (an MJCF model)");
  std::string meshdir, texturedir;
  w.children(root, [&](const x::XMLElement* e) {
    if (std::string(e->Name()) != "compiler") return;
    if (const char* a = e->Attribute("assetdir")) meshdir = texturedir = a;
    if (const char* a = e->Attribute("meshdir")) meshdir = a;
    if (const char* a = e->Attribute("texturedir")) texturedir = a;
  });
  const std::function<void(const x::XMLElement*)> assets = [&](const x::XMLElement* e) {
    const std::string name = e->Name();
    const std::string& dir = name == "texture" ? texturedir : meshdir;
    for (const char* attr : {"file", "fileright", "fileleft", "fileup", "filedown", "filefront", "fileback"}) {
      const char* f = e->Attribute(attr);
      if (!f) continue;
      const std::string what = "<" + name + " " + attr + "=\"" + f + "\">";
      w.file(w.resolve(dir, f, what), what);
    }
  };
  w.children(root, [&](const x::XMLElement* e) {
    if (std::string(e->Name()) == "asset") w.children(e, assets);
  });
  // Includes nested in any section are read by walking the sections.
  const std::function<void(const x::XMLElement*)> deep = [&](const x::XMLElement* e) { w.children(e, deep); };
  w.children(root, deep);
}

// Sensor dimensions by element name (MuJoCo 2.2.2's sensor types).
int sensor_dim(const x::XMLElement* e, const std::string& model) {
  static const std::map<std::string, int> dims = {
      {"touch", 1},          {"accelerometer", 3},  {"velocimeter", 3},    {"gyro", 3},          {"force", 3},
      {"torque", 3},         {"magnetometer", 3},   {"rangefinder", 1},    {"jointpos", 1},      {"jointvel", 1},
      {"tendonpos", 1},      {"tendonvel", 1},      {"actuatorpos", 1},    {"actuatorvel", 1},   {"actuatorfrc", 1},
      {"ballquat", 4},       {"ballangvel", 3},     {"jointlimitpos", 1},  {"jointlimitvel", 1}, {"jointlimitfrc", 1},
      {"tendonlimitpos", 1}, {"tendonlimitvel", 1}, {"tendonlimitfrc", 1}, {"framepos", 3},      {"framequat", 4},
      {"framexaxis", 3},     {"frameyaxis", 3},     {"framezaxis", 3},     {"framelinvel", 3},   {"frameangvel", 3},
      {"framelinacc", 3},    {"frameangacc", 3},    {"subtreecom", 3},     {"subtreelinvel", 3}, {"subtreeangmom", 3},
      {"clock", 1}};
  const std::string n = e->Name();
  if (n == "user") return e->IntAttribute("dim", 0);
  auto it = dims.find(n);
  if (it == dims.end()) throw ModelError(model + ": <sensor> holds <" + n + ">, not a sensor MuJoCo 2.2.2 knows");
  return it->second;
}

std::string attr(const x::XMLElement* e, const char* name) {
  const char* a = e->Attribute(name);
  return a ? a : "";
}

}  // namespace

bool path_inside_folder(const std::string& path) {
  if (path.empty() || path[0] == '/' || path.find('\\') != std::string::npos || path.find('\0') != std::string::npos)
    return false;
  std::stringstream ss(path);
  std::string part;
  while (std::getline(ss, part, '/'))
    if (part == "..") return false;
  return true;
}

void read_model_folder(const std::string& model_path, config::TermsConfig* cfg) {
  const size_t slash = model_path.find_last_of('/');
  const std::string folder = slash == std::string::npos ? "." : model_path.substr(0, slash);
  const std::string main = model_path.substr(slash == std::string::npos ? 0 : slash + 1);
  const int64_t bound = std::min<int64_t>(cfg->max_model_bytes(), kMaxModelBytesCap);
  std::map<std::string, std::string> files;
  std::vector<std::string> order;
  int64_t total = 0;
  const FileSource from_disk = [&](const std::string& rel, const std::string& what) -> const std::string& {
    auto it = files.find(rel);
    if (it != files.end()) return it->second;
    const std::string path = folder + "/" + rel;
    std::ifstream in(path, std::ios::binary);
    if (!in) throw ModelError(model_path + ": " + what + ": cannot open '" + path + "'");
    std::ostringstream ss;
    ss << in.rdbuf();
    total += int64_t(ss.str().size());
    if (total > bound)
      throw ModelError(model_path + ": the model's files come to more than " + std::to_string(bound) +
                       " bytes (task.terms.max_model_bytes) with '" + rel + "' (" + std::to_string(ss.str().size()) +
                       " bytes)");
    if (int(files.size()) >= kMaxModelFiles)
      throw ModelError(model_path + ": more than " + std::to_string(kMaxModelFiles) + " files");
    order.push_back(rel);
    return files.emplace(rel, ss.str()).first->second;
  };
  ModelWalker w(main, from_disk);
  walk_files(w);
  cfg->clear_model_files();
  for (const auto& rel : order) {
    auto* f = cfg->add_model_files();
    f->set_path(rel);
    f->set_data(files[rel]);
  }
  cfg->set_model(main);
  check_bundle(*cfg);
}

void check_bundle(const config::TermsConfig& cfg) {
  const std::string& model = cfg.model();
  if (model.empty()) throw ModelError("task.terms.model: required (the MJCF file of the robot)");
  if (!path_inside_folder(model))
    throw ModelError("task.terms.model '" + model + "' is an absolute path or leaves its folder; refused");
  if (cfg.model_files_size() > kMaxModelFiles)
    throw ModelError("task.terms.model_files: " + std::to_string(cfg.model_files_size()) + " files, at most " +
                     std::to_string(kMaxModelFiles));
  const int64_t bound = std::min<int64_t>(cfg.max_model_bytes(), kMaxModelBytesCap);
  int64_t total = 0;
  std::map<std::string, const std::string*> files;
  std::set<std::string> bases;
  for (const auto& f : cfg.model_files()) {
    if (!path_inside_folder(f.path()) || normalize(f.path()) != f.path())
      throw ModelError("task.terms.model_files: '" + f.path() +
                       "' is an absolute path or leaves its folder, or is not in normal form; refused");
    if (!bases.insert(base_name(f.path())).second)
      throw ModelError("task.terms.model_files: two files named '" + base_name(f.path()) +
                       "' (MuJoCo's virtual file system keys files by their base name)");
    total += int64_t(f.data().size());
    if (total > bound)
      throw ModelError("task.terms.model_files: more than " + std::to_string(bound) +
                       " bytes (task.terms.max_model_bytes) with '" + f.path() + "'");
    files[f.path()] = &f.data();
  }
  const FileSource from_bundle = [&](const std::string& rel, const std::string& what) -> const std::string& {
    auto it = files.find(rel);
    if (it == files.end())
      throw ModelError(model + ": " + what + ": '" + rel + "' is not among the model's files (task.terms.model_files)");
    return *it->second;
  };
  ModelWalker w(model, from_bundle);
  walk_files(w);
}

int JointInfo::qpos_size() const { return type == "free" ? 7 : type == "ball" ? 4 : 1; }
int JointInfo::dof_size() const { return type == "free" ? 6 : type == "ball" ? 3 : 1; }
int ModelInfo::nq() const {
  int n = 0;
  for (const auto& j : joints) n += j.qpos_size();
  return n;
}
int ModelInfo::nv() const {
  int n = 0;
  for (const auto& j : joints) n += j.dof_size();
  return n;
}

ModelInfo scan_model(const config::TermsConfig& cfg) {
  std::map<std::string, const std::string*> files;
  for (const auto& f : cfg.model_files()) files[f.path()] = &f.data();
  const FileSource from_bundle = [&](const std::string& rel, const std::string& what) -> const std::string& {
    auto it = files.find(rel);
    if (it == files.end())
      throw ModelError(cfg.model() + ": " + what + ": '" + rel + "' is not among the model's files");
    return *it->second;
  };
  ModelWalker w(cfg.model(), from_bundle);
  const x::XMLElement* root = w.root();
  if (!root || std::string(root->Name()) != "mujoco")
    throw ModelError(cfg.model() + ": expected a <mujoco> root element (an MJCF model)");

  // Default classes: each class's parent and the joint type it sets.
  std::map<std::string, std::pair<std::string, std::string>> classes;  // name -> (parent, joint type)
  const std::function<void(const x::XMLElement*, const std::string&)> defaults = [&](const x::XMLElement* d,
                                                                                     const std::string& parent) {
    const std::string name = d->Attribute("class") ? d->Attribute("class") : (parent.empty() ? "main" : "");
    if (name.empty()) throw ModelError(cfg.model() + ": a nested <default> without a class");
    std::string type;
    w.children(d, [&](const x::XMLElement* e) {
      const std::string n = e->Name();
      if (n == "joint" && e->Attribute("type")) type = e->Attribute("type");
      if (n == "default") defaults(e, name);
    });
    classes[name] = {parent, type};
  };
  w.children(root, [&](const x::XMLElement* e) {
    if (std::string(e->Name()) == "default") defaults(e, "");
  });
  const auto joint_type = [&](const x::XMLElement* j, const std::string& childclass) {
    if (const char* t = j->Attribute("type")) return std::string(t);
    std::string c = j->Attribute("class") ? j->Attribute("class") : childclass;
    for (int hops = 0; !c.empty() && hops < 64; ++hops) {
      auto it = classes.find(c);
      if (it == classes.end()) throw ModelError(cfg.model() + ": joint class '" + c + "' is not defined");
      if (!it->second.second.empty()) return it->second.second;
      c = it->second.first;
    }
    return std::string("hinge");
  };

  ModelInfo info;
  info.bodies.push_back("world");  // MuJoCo names body 0 so
  const std::function<void(const x::XMLElement*, const std::string&)> body = [&](const x::XMLElement* b,
                                                                                 const std::string& inherited) {
    const std::string cls = b->Attribute("childclass") ? b->Attribute("childclass") : inherited;
    std::vector<const x::XMLElement*> kids;
    w.children(b, [&](const x::XMLElement* e) {
      const std::string n = e->Name();
      if (n == "joint") info.joints.push_back({attr(e, "name"), joint_type(e, cls)});
      if (n == "freejoint") info.joints.push_back({attr(e, "name"), "free"});
      if (n == "geom") info.geoms.push_back(attr(e, "name"));
      if (n == "body") kids.push_back(e);
    });
    // MuJoCo numbers bodies depth first; a body's joints and geoms come before its children's.
    for (const x::XMLElement* k : kids) {
      info.bodies.push_back(attr(k, "name"));
      body(k, cls);
    }
  };
  w.children(root, [&](const x::XMLElement* e) {
    const std::string n = e->Name();
    if (n == "worldbody") body(e, "main");
  });
  w.children(root, [&](const x::XMLElement* e) {
    const std::string n = e->Name();
    if (n == "actuator")
      w.children(e, [&](const x::XMLElement* a) {
        info.actuators.push_back(attr(a, "name"));
        info.actuator_joints.push_back(attr(a, "joint"));
      });
    if (n == "sensor")
      w.children(e, [&](const x::XMLElement* s) {
        info.sensors.push_back({attr(s, "name"), sensor_dim(s, cfg.model())});
      });
    if (n == "keyframe") w.children(e, [&](const x::XMLElement* k) { info.keyframes.push_back(attr(k, "name")); });
  });
  return info;
}

}  // namespace farm::robots::terms
