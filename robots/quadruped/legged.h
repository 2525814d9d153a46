// The legged-robot layer the quadruped tasks share, after the environment interface of the MushroomRL paper
// §3.2: an observation specification (named properties of named bodies and joints, plus custom
// slots with bounds), reading and writing named properties, collision groups with "did A touch B"
// and "net contact force on each member of a group" queries, and intermediate control steps (a
// controller recomputed before every physics step) with hooks before and after each step.
#pragma once

#include <functional>
#include <random>
#include <string>
#include <vector>

struct mjModel_;
struct mjData_;

namespace farm::robots::legged {

// Properties the specification can name (MushroomRL paper §3.2.1: properties of registered prims).
enum class Property {
  kBodyHeight,        // world z of a body's frame (1)
  kBodyLinVelLocal,   // linear velocity of a body in its own frame (3)
  kBodyAngVelLocal,   // angular velocity of a body in its own frame (3)
  kProjectedGravity,  // unit gravity direction in a body's frame (3)
  kJointPos,          // hinge/slide joint position (1)
  kJointVel,          // hinge/slide joint velocity (1)
  kCustom,            // a slot the task fills (size given), normalized from [low, high] to [-1, 1]
};

int property_size(Property p);

struct ObsItem {
  std::string label;  // "base_lin_vel", "dof_pos", ...
  Property property = Property::kCustom;
  std::vector<int> ids;           // body or joint ids (one block of property_size each); empty for custom
  int size = 0;                   // floats in the observation
  double scale = 1.0;             // multiplied in after subtracting offset
  std::vector<double> offset;     // per float (e.g. the default joint pose); empty = 0
  double noise = 0.0;             // uniform in +-noise * scale (times the noise level)
  double low = -1.0, high = 1.0;  // custom slots only: the range mapped to [-1, 1]
  int start = 0;                  // offset in the observation, set by ObsSpec::add
};

class ObsSpec {
 public:
  // Appends an item; returns its start offset.
  int add(ObsItem item);
  int dim() const { return dim_; }
  const std::vector<ObsItem>& items() const { return items_; }
  const ObsItem& item(const std::string& label) const;  // throws std::out_of_range naming it

 private:
  std::vector<ObsItem> items_;
  int dim_ = 0;
};

// Reads a property of body/joint `id` into out (property_size floats).
void read_property(const mjModel_* m, const mjData_* d, Property p, int id, double* out);
// Writes a joint position or velocity, or a body's (free-joint root) height or local linear
// velocity; throws std::invalid_argument for properties that cannot be written.
void write_property(const mjModel_* m, mjData_* d, Property p, int id, const double* value);

// Builds the observation: named properties, scaled, offset and noised; custom slots are taken from
// `custom` (label -> values in [low, high]) in order of appearance. noise_level 0 turns noise off.
void build_observation(const mjModel_* m, const mjData_* d, const ObsSpec& spec,
                       const std::vector<std::vector<double>>& custom, double noise_level, std::mt19937_64& rng,
                       float* obs);

// A named set of geoms (MushroomRL paper §3.2.4).
struct CollisionGroup {
  std::string name;
  std::vector<int> geoms;
};

// Geom ids by name; throws std::invalid_argument naming the geom that is missing.
CollisionGroup make_group(const mjModel_* m, const std::string& name, const std::vector<std::string>& geom_names);

// True when any geom of a touches any geom of b in the current contacts.
bool touching(const mjModel_* m, const mjData_* d, const CollisionGroup& a, const CollisionGroup& b);
// Number of members of a that touch any geom of b.
int count_touching(const mjModel_* m, const mjData_* d, const CollisionGroup& a, const CollisionGroup& b);
// Net contact force (world frame, 3 per member) on each geom of the group, summed over its contacts:
// a pressure-sensor view of the group.
void net_contact_forces(const mjModel_* m, const mjData_* d, const CollisionGroup& g, std::vector<double>& out);

// Intermediate control steps (MushroomRL paper §3.2.2): `steps` times, the controller writes d->ctrl from
// the current state, `before` runs, mj_step advances, `after` runs. Hooks may be empty.
struct ControlHooks {
  std::function<void(mjData_*)> before;
  std::function<void(mjData_*)> after;
};
void control_steps(const mjModel_* m, mjData_* d, int steps, const std::function<void(mjData_*)>& controller,
                   const ControlHooks& hooks = {});

// Ids by name; throw std::invalid_argument naming what is missing from which model.
int body_id(const mjModel_* m, const std::string& name);
int joint_id(const mjModel_* m, const std::string& name);
int geom_id(const mjModel_* m, const std::string& name);

}  // namespace farm::robots::legged
