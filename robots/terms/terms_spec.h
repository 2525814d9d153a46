// The task of terms as seen without MuJoCo: the catalogue of terms (terms_catalogue.def), what a
// config's terms resolve to over the model (which joints, bodies, sensors; how many floats), the
// task's TaskSpec, and the quantities a reward expression may name. The learner sizes its networks
// from this; the worker's TermsTask (terms_task.h) builds on the same resolution, so the two agree.
#pragma once

#include <string>
#include <vector>

#include "farm_config.pb.h"
#include "mjcf_bundle.h"
#include "task_spec.h"

namespace farm::robots::terms {

// What a term's `names` select. Contacts / ContactsRequired: bodies by `names`, or geoms by the
// term's `geoms` in place of them (a foot that is one geom of a calf body); Contacts with neither
// selects the root body. Geoms is what `geoms` and `other` select from. AllBodies: bodies as
// Bodies, but empty selects every body of the model, the world (id 0) first: the whole of one of
// MuJoCo's per-body arrays, as Gymnasium's Humanoid-v4 observes data.cinert, cvel and cfrc_ext.
enum class Names { None, Joints, Bodies, BodiesRequired, AllBodies, Sensors, Geoms, Contacts, ContactsRequired };

inline constexpr int kQpos = -1, kQvel = -2, kSensorDim = -3, kActDim = -4;

struct TermInfo {
  const char* name;
  Names names;
  int item_size;       // observation terms only
  const char* params;  // space-separated field names the term reads
};

const std::vector<TermInfo>& observation_terms();
const std::vector<TermInfo>& reward_terms();
const std::vector<TermInfo>& termination_terms();

// The items `names` selects from the model: each entry is a name or an ECMAScript regular expression
// matched against whole names; empty selects the default of the kind. Returns indices (MuJoCo ids:
// joints and bodies as numbered by MuJoCo). Throws std::invalid_argument naming the entry that
// matches nothing and the names there are.
std::vector<int> select(Names kind, const google::protobuf::RepeatedPtrField<std::string>& names,
                        const ModelInfo& model, int root_body);

// The items of a contact term: the geoms `geoms` selects, each an item, when it is not empty; else
// the bodies `names` selects (kind Contacts or ContactsRequired). `by_geom` says which.
std::vector<int> contact_items(Names kind, const google::protobuf::RepeatedPtrField<std::string>& names,
                               const google::protobuf::RepeatedPtrField<std::string>& geoms, const ModelInfo& model,
                               int root, bool* by_geom = nullptr);

// The root body's id: terms.root_body, or the first body below the world.
int root_body(const config::TermsConfig& cfg, const ModelInfo& model);

// The joints the action drives ("position") or the actuators it sets ("actuator").
std::vector<int> action_targets(const config::TermsConfig& cfg, const ModelInfo& model);

// Floats of one observation term.
int observation_size(const config::ObsTerm& term, const ModelInfo& model, int root, int act_dim);

// Names a reward expression may use, in the order terms_task.cpp fills them.
std::vector<std::string> expression_quantities(const ModelInfo& model);

// The metrics every task of terms reports: root displacement along x (m), 1 if a termination term
// ended the episode, episode time (s), then each reward term's episode sum of weight x value
// ("reward.<term>", with a suffix when a term is listed twice), then each term's per-step mean of
// its value before the weight ("mean.<term>": a tracking term's mean is the share of the command
// met).
std::vector<std::string> metric_names(const config::TermsConfig& cfg);

// The TaskSpec of task "terms" (model_files filled). Throws std::invalid_argument or ModelError.
TaskSpec task_spec(const config::TermsConfig& cfg);
// The same from the task section (robots/tasks.def).
TaskSpec terms_spec(const config::TaskConfig& cfg);

}  // namespace farm::robots::terms
