// The config's text and files around the checks of config.cpp: loading, printing, the fields a
// config from the bus may not set, and the derived values both sides read.
#include <google/protobuf/text_format.h>

#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "config.h"

namespace farm {

namespace pb = google::protobuf;

std::vector<std::string> algorithm_sections() {
  std::vector<std::string> names;
  const pb::Descriptor* d = config::ExperimentConfig::descriptor();
  for (int i = 0; i < d->field_count(); ++i)
    if (d->field(i)->options().GetExtension(config::algorithm_section)) names.push_back(d->field(i)->name());
  return names;
}

namespace {

// Fields that name a file to write (marked output_path in the schema); found at any depth.
bool is_output_path(const pb::FieldDescriptor* f) { return f->options().GetExtension(config::output_path); }

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

config::ExperimentConfig parse_config_from_bus(const std::string& text, const std::string& source,
                                               const TaskKnowledge& tasks) {
  config::ExperimentConfig cfg;
  try {
    cfg = parse_config_text(text, source, "", tasks);
  } catch (const ConfigError& e) {
    // The sender knows a field this program does not: a newer build. Said first, so a cut message keeps it.
    if (std::string(e.what()).find("has no field named") == std::string::npos) throw;
    throw ConfigError(
        source + " was written by a newer build than this program (update this host's farm programs): " + e.what());
  }
  const std::vector<std::string> paths = output_path_fields(cfg);
  if (!paths.empty())
    throw ConfigError(source + ": field '" + paths.front() +
                      "' names a file for this host to write; a config received over the bus may not");
  return cfg;
}

config::ExperimentConfig load_config_file(const std::string& path, const TaskKnowledge& tasks) {
  std::ifstream in(path);
  if (!in) throw ConfigError(path + ": cannot open config file");
  std::stringstream ss;
  ss << in.rdbuf();
  const size_t slash = path.find_last_of('/');
  return parse_config_text(ss.str(), path, slash == std::string::npos ? "." : path.substr(0, slash), tasks);
}

std::string config_to_text(const config::ExperimentConfig& cfg) {
  std::string out;
  pb::TextFormat::PrintToString(cfg, &out);
  return out;
}

bool valid_device_name(const std::string& name) {
  if (name == "cpu" || name == "cuda" || name == "auto") return true;
  const std::string prefix = "cuda:";
  if (name.size() <= prefix.size() || name.compare(0, prefix.size(), prefix) != 0) return false;
  for (size_t i = prefix.size(); i < name.size(); ++i)
    if (name[i] < '0' || name[i] > '9') return false;
  return name.size() - prefix.size() <= 3;
}

std::vector<int> sac_hidden(const config::SacConfig& sac) {
  if (sac.hidden_size() == 0) return {256, 256};  // sb3 SAC net_arch (mCLARI thesis §4.3.2)
  return {sac.hidden().begin(), sac.hidden().end()};
}

std::vector<int> sac_critic_hidden(const config::SacConfig& sac) {
  if (sac.critic_hidden_size() == 0) return sac_hidden(sac);
  return {sac.critic_hidden().begin(), sac.critic_hidden().end()};
}

}  // namespace farm
