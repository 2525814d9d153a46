// The task of terms (robots/terms/): its configs' errors name FILE:LINE:COL, its model travels as a
// checked bundle (nothing outside the model's folder, nothing oversized, nothing from the bus read as
// a path), its scan of the MJCF agrees with MuJoCo, and its terms compute what they say. The shipped
// configs against Gymnasium's definitions are in test_terms_gymnasium.cpp.
#include <google/protobuf/text_format.h>
#include <gtest/gtest.h>
#include <mujoco/mujoco.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <random>
#include <regex>
#include <string>

#include "config.h"
#include "task.h"
#include "task_specs.h"
#include "terms/mjcf_bundle.h"
#include "terms/terms_spec.h"
#include "terms/terms_task.h"
#include "terms_testing.h"

namespace farm::robots::terms {
namespace {

// A config of the HalfCheetah model with `terms` as the body of task.terms (after the model line).
std::string cheetah(const std::string& terms) {
  return "experiment_id: \"t\"\n"
         "task {\n"
         "  name: \"terms\"\n"
         "  terms {\n"
         "    model: \"models/half_cheetah/half_cheetah.xml\"\n" +
         terms +
         "  }\n"
         "}\n";
}

// The ConfigError's text of loading `text` as my.txtpb in deploy/configs ("" when it loads).
std::string error_of(const std::string& text, const std::string& folder = kConfigs) {
  try {
    parse_config_text(text, "my.txtpb", folder);
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

const std::string kObs = "    observation { term: \"qpos\" skip: 1 }\n";

TEST(TermsConfig, AnUnknownTermIsNamedWithItsPlaceAndTheKnownTerms) {
  const std::string e = error_of(cheetah(kObs + "    observation { term: \"qpoz\" }\n"));
  EXPECT_NE(e.find("my.txtpb:7:19: field 'task.terms.observation[1].term': unknown term 'qpoz'"), std::string::npos)
      << e;
  EXPECT_NE(e.find("known: joint_pos, "), std::string::npos) << e;
  const std::string r = error_of(cheetah(kObs + "    reward { term: \"speed\" }\n"));
  EXPECT_NE(r.find("my.txtpb:7:14: field 'task.terms.reward[0].term': unknown term 'speed'"), std::string::npos) << r;
  const std::string t = error_of(cheetah(kObs + "    termination { term: \"fall\" }\n"));
  EXPECT_NE(t.find("field 'task.terms.termination[0].term': unknown term 'fall'; known: body_contact"),
            std::string::npos)
      << t;
}

TEST(TermsConfig, AParameterTheTermDoesNotReadOrOutOfRangeIsNamed) {
  const std::string e = error_of(cheetah(kObs + "    reward { term: \"alive\" names: \"torso\" }\n"));
  EXPECT_NE(e.find("my.txtpb:7:28: field 'task.terms.reward[0].names': term 'alive' does not read 'names'"),
            std::string::npos)
      << e;
  const std::string s = error_of(cheetah(kObs + "    reward { term: \"lin_vel_tracking\" sigma: -1 }\n"));
  EXPECT_NE(s.find("my.txtpb:7:39: field 'task.terms.reward[0].sigma': expected > 0, got -1"), std::string::npos) << s;
  const std::string k = error_of(cheetah(kObs + "    observation { term: \"qvel\" skip: 10 }\n"));
  EXPECT_NE(k.find("field 'task.terms.observation[1].skip': expected 0..9 (the model's nv), got 10"), std::string::npos)
      << k;
  const std::string x = error_of(cheetah(kObs + "    reward { term: \"expression\" expression: \"2 * x_vell\" }\n"));
  EXPECT_NE(x.find("my.txtpb:7:33: field 'task.terms.reward[0].expression': muparser: "), std::string::npos) << x;
  EXPECT_NE(x.find("quantities: x_vel, "), std::string::npos) << x;
}

TEST(TermsConfig, ABodyJointOrSensorNameTheModelLacksIsNamedWithTheNamesThereAre) {
  const std::string e = error_of(cheetah(kObs + "    termination { term: \"body_contact\" names: \"torsoo\" }\n"));
  EXPECT_NE(e.find("my.txtpb:7:40: field 'task.terms.termination[0].names': names: 'torsoo' matches no body of the "
                   "model; there are: torso, bthigh"),
            std::string::npos)
      << e;
  const std::string j =
      error_of(cheetah(kObs + "    observation { term: \"joint_pos\" names: \"bthigh\" names: \"knee.*\" }\n"));
  EXPECT_NE(j.find("my.txtpb:7:53: field 'task.terms.observation[1].names': names: 'knee.*' matches no hinge or slide "
                   "joint"),
            std::string::npos)
      << j;
  const std::string a =
      error_of(cheetah(kObs + "    action { type: \"actuator\" names: \"bthigh\" names: \"tail\" }\n"));
  EXPECT_NE(a.find("field 'task.terms.action.names': names: 'tail' matches no actuator"), std::string::npos) << a;
  // A contact term's geoms and the geoms it counts contacts with, and the reset's geoms.
  const std::string g = error_of(
      cheetah(kObs + "    reward { term: \"collision\" geoms: \"bthigh\" geoms: \"claw\" other: \"floor\" }\n"));
  EXPECT_NE(g.find("my.txtpb:7:48: field 'task.terms.reward[0].geoms': names: 'claw' matches no geom of the model; "
                   "there are: floor, torso"),
            std::string::npos)
      << g;
  const std::string o =
      error_of(cheetah(kObs + "    termination { term: \"body_contact\" geoms: \"torso\" other: \"flor\" }\n"));
  EXPECT_NE(o.find("field 'task.terms.termination[0].other': names: 'flor' matches no geom"), std::string::npos) << o;
  const std::string b =
      error_of(cheetah(kObs + "    termination { term: \"body_contact\" names: \"torso\" geoms: \"torso\" }\n"));
  EXPECT_NE(b.find("field 'task.terms.termination[0].geoms': a contact term reads bodies (names) or geoms, not both"),
            std::string::npos)
      << b;
  const std::string r = error_of(cheetah(kObs + "    reset { clear_geoms: \"fot\" }\n"));
  EXPECT_NE(r.find("field 'task.terms.reset.clear_geoms': names: 'fot' matches no geom"), std::string::npos) << r;
}

// A folder under the test's temporary directory with the given files.
std::string folder_with(const std::string& name, const std::vector<std::pair<std::string, std::string>>& files) {
  const std::string dir = ::testing::TempDir() + "/terms_" + name;
  std::filesystem::remove_all(dir);
  for (const auto& [path, text] : files) {
    std::filesystem::create_directories(std::filesystem::path(dir + "/" + path).parent_path());
    std::ofstream(dir + "/" + path, std::ios::binary) << text;
  }
  return dir;
}

std::string config_of(const std::string& model, const std::string& extra = "") {
  return "experiment_id: \"t\"\ntask { name: \"terms\" terms {\n  model: \"" + model + "\"\n" + extra +
         "  observation { term: \"qpos\" }\n} }\n";
}

const std::string kSliderWithInclude =
    "<mujoco><worldbody><include file=\"%s\"/></worldbody>"
    "<actuator><motor joint=\"s\"/></actuator></mujoco>";

std::string with_include(const std::string& file) {
  return std::regex_replace(kSliderWithInclude, std::regex("%s"), file);
}

const std::string kSliderBody =
    "<mujoco><body name=\"b\"><joint name=\"s\" type=\"slide\"/><geom size=\"0.1\"/></body></mujoco>";

TEST(TermsModel, FilesOutsideTheModelsFolderAreRefusedAtTheLearnerNamingThem) {
  const std::string dir = folder_with("outside", {{"robot/robot.xml", with_include("../secret.xml")},
                                                  {"secret.xml", kSliderBody},
                                                  {"robot/abs.xml", with_include("/etc/hostname")},
                                                  {"robot/mesh.xml",
                                                   "<mujoco><compiler meshdir=\"../meshes\"/><asset><mesh name=\"m\" "
                                                   "file=\"m.stl\"/></asset><worldbody/></mujoco>"}});
  const std::string e = error_of(config_of("robot/robot.xml"), dir);
  EXPECT_NE(e.find("my.txtpb:3:3: field 'task.terms.model': robot.xml: <include file=\"../secret.xml\"> names "
                   "'../secret.xml', outside the model's folder"),
            std::string::npos)
      << e;
  const std::string a = error_of(config_of("robot/abs.xml"), dir);
  EXPECT_NE(a.find("<include file=\"/etc/hostname\"> names '/etc/hostname', outside the model's folder"),
            std::string::npos)
      << a;
  const std::string m = error_of(config_of("robot/mesh.xml"), dir);
  EXPECT_NE(m.find("<mesh file=\"m.stl\"> names '../meshes/m.stl', outside the model's folder"), std::string::npos)
      << m;
  // The same model with its include inside the folder loads, the included file in the bundle.
  const std::string ok = folder_with(
      "inside", {{"robot/robot.xml", with_include("parts/slider.xml")}, {"robot/parts/slider.xml", kSliderBody}});
  const auto cfg = parse_config_text(config_of("robot/robot.xml"), "my.txtpb", ok);
  ASSERT_EQ(cfg.task().terms().model_files_size(), 2);
  EXPECT_EQ(cfg.task().terms().model(), "robot.xml");
  EXPECT_EQ(cfg.task().terms().model_files(1).path(), "parts/slider.xml");
  EXPECT_EQ(make_task(cfg.task())->spec().obs_dim, 1);
  // A model named by an absolute path is read from there, not from the config's folder.
  const auto abs = parse_config_text(config_of(ok + "/robot/robot.xml"), "my.txtpb", "/nonexistent");
  EXPECT_EQ(abs.task().terms().model_files_size(), 2);
}

TEST(TermsModel, AModelOverItsBoundIsRefusedNamingTheFileAndTheField) {
  const std::string dir = folder_with("big", {{"robot/robot.xml", with_include("parts/slider.xml")},
                                              {"robot/parts/slider.xml", kSliderBody + std::string(4000, ' ')}});
  const std::string e = error_of(config_of("robot/robot.xml", "  max_model_bytes: 2000\n"), dir);
  EXPECT_NE(e.find("terms_big/robot/robot.xml: the model's files come to more than 2000 bytes "
                   "(task.terms.max_model_bytes) with 'parts/slider.xml'"),
            std::string::npos)
      << e;
  // The bound itself is bounded: a spec cannot ask a worker to hold more than kMaxModelBytesCap.
  const std::string cap = error_of(config_of("robot/robot.xml", "  max_model_bytes: 1000000000\n"), dir);
  EXPECT_NE(cap.find("field 'task.terms.max_model_bytes': expected 1..67108864"), std::string::npos) << cap;
}

// A config as a worker receives it: the model's files inline, from whoever published the spec.
config::ExperimentConfig from_bus(const std::string& model,
                                  const std::vector<std::pair<std::string, std::string>>& files) {
  config::ExperimentConfig c = load_config_file(kConfigs + "/half_cheetah_sac.txtpb");
  auto* t = c.mutable_task()->mutable_terms();
  t->set_model(model);
  t->clear_model_files();
  for (const auto& [p, d] : files) {
    auto* f = t->add_model_files();
    f->set_path(p);
    f->set_data(d);
  }
  return c;
}

std::string bus_error(const config::ExperimentConfig& c) {
  try {
    parse_config_from_bus(config_to_text(c), "ExperimentSpec(t)");
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

TEST(TermsModel, ASpecFromTheBusNamingAPathIsRefusedAndNothingIsRead) {
  const std::string cheetah_xml =
      load_config_file(kConfigs + "/half_cheetah_sac.txtpb").task().terms().model_files(0).data();
  // Files that exist on this host: a worker that opened them would load something.
  const std::string on_disk = kConfigs + "/models/half_cheetah/half_cheetah.xml";
  for (const auto& [model, path] : std::vector<std::pair<std::string, std::string>>{
           {on_disk, "half_cheetah.xml"},                // the model named by an absolute path
           {"../half_cheetah.xml", "half_cheetah.xml"},  // ... or by '..'
           {"half_cheetah.xml", on_disk},                // a bundled file under an absolute path
           {"half_cheetah.xml", "a/../../half_cheetah.xml"}}) {
    const auto c = from_bus(model, {{path, cheetah_xml}});
    const std::string e = bus_error(c);
    EXPECT_NE(e.find("ExperimentSpec(t)"), std::string::npos) << model << " / " << path << ": " << e;
    EXPECT_NE(e.find("is an absolute path or leaves its folder"), std::string::npos)
        << model << " / " << path << ": " << e;
    // The worker's task refuses it too, whatever checked the config before.
    EXPECT_THROW(make_task(c.task()), ModelError) << model << " / " << path;
  }
  // A file the MJCF names that the bundle lacks is refused before MuJoCo sees the model: MuJoCo's
  // virtual file system would read a missing name from the disk.
  const auto missing = from_bus("robot.xml", {{"robot.xml", with_include(on_disk.substr(1))}});
  EXPECT_NE(bus_error(missing).find("is not among the model's files (task.terms.model_files)"), std::string::npos)
      << bus_error(missing);
  EXPECT_THROW(make_task(missing.task()), ModelError);
}

TEST(TermsModel, TheScanOfTheMjcfIsWhatMuJoCoCompiles) {
  for (const char* name : {"half_cheetah_sac", "hexapod_sac", "hopper_sac", "walker2d_sac", "ant_sac"}) {
    const auto cfg = load_config_file(kConfigs + "/" + name + ".txtpb").task().terms();
    const ModelInfo info = scan_model(cfg);
    mjModel* m = load_bundle(cfg);
    ASSERT_NE(m, nullptr);
    EXPECT_EQ(info.nq(), m->nq) << name;
    EXPECT_EQ(info.nv(), m->nv) << name;
    ASSERT_EQ(int(info.bodies.size()), m->nbody) << name;
    for (int b = 0; b < m->nbody; ++b)
      EXPECT_EQ(info.bodies[b], mj_id2name(m, mjOBJ_BODY, b) ? mj_id2name(m, mjOBJ_BODY, b) : "");
    ASSERT_EQ(int(info.joints.size()), m->njnt) << name;
    for (int j = 0; j < m->njnt; ++j) EXPECT_EQ(info.joints[j].name, mj_id2name(m, mjOBJ_JOINT, j)) << name;
    EXPECT_EQ(int(info.actuators.size()), m->nu) << name;
    int sensor_floats = 0;
    for (const auto& s : info.sensors) sensor_floats += s.dim;
    EXPECT_EQ(sensor_floats, m->nsensordata) << name;
    mj_deleteModel(m);
  }
  // The hexapod: its legs from an include, its joints' types from default classes.
  const auto hex = load_config_file(kConfigs + "/hexapod_sac.txtpb").task().terms();
  EXPECT_EQ(hex.model_files_size(), 3);
  const TaskSpec s = task_spec(hex);
  EXPECT_EQ(s.act_dim, 12);
  EXPECT_EQ(s.obs_dim, 3 + 3 + 3 + 12 + 12 + 12 + 6);
}

TEST(TermsTask, AnExpressionRewardIsTheFormulaOverItsQuantities) {
  Cheetah c(
      "reward { term: \"expression\" expression: \"2 * x_vel - action_sq + (height > 0.5 ? 1 : 0)\" weight: 0.5 }");
  const std::vector<float> a = {0.5f, -0.3f, 0.9f, -1.0f, 0.2f, 0.0f};
  double ctrl = 0;
  for (float x : a) ctrl += double(x) * x;
  for (int t = 0; t < 20; ++t) {
    const double x_before = c.s().data->qpos[0];
    const StepResult r = c.task->step(*c.state, a.data(), c.obs.data());
    const mjData* d = c.s().data;
    mjtNum res[6];  // the root's world velocity: angular, then linear
    mj_objectVelocity(c.task->model(), d, mjOBJ_BODY, 1, res, 0);
    const double expr = 2 * res[3] - ctrl + (d->xpos[3 + 2] > 0.5 ? 1 : 0);
    EXPECT_NEAR(r.reward, (d->qpos[0] - x_before) / 0.05 - 0.1 * ctrl + 0.5 * expr, 1e-4) << "step " << t;
  }
  // The per-term episode sums are the episode's metrics after the three common ones, then each
  // term's per-step mean before its weight.
  const auto names = c.task->spec().metric_names;
  ASSERT_EQ(names.size(), 9u);
  EXPECT_EQ(names[3], "reward.joint_progress");
  EXPECT_EQ(names[5], "reward.expression");
  EXPECT_EQ(names[6], "mean.joint_progress");
  EXPECT_EQ(names[8], "mean.expression");
  std::vector<float> m(names.size());
  c.task->episode_metrics(*c.state, m.data());
  EXPECT_NEAR(m[3] + m[4] + m[5], c.state->episode_return, 1e-3);
  ASSERT_EQ(c.state->step, 20);
  EXPECT_NEAR(m[5], 0.5 * 20 * m[8], 1e-3 * std::max(1.f, std::abs(m[5])));
  EXPECT_NEAR(m[7], ctrl, 1e-4);  // ctrl_cost before its weight: the same action on every step
}

TEST(TermsTask, TerminationsEndTheEpisodeAndSayWhy) {
  // A height band the cheetah's torso leaves at once: the episode ends on the first step.
  Cheetah c("termination { term: \"height\" min: 5 }");
  const std::vector<float> a(6, 0.f);
  const StepResult r = c.task->step(*c.state, a.data(), c.obs.data());
  EXPECT_TRUE(r.terminated);
  std::vector<float> m(c.task->spec().metric_names.size());
  c.task->episode_metrics(*c.state, m.data());
  EXPECT_EQ(m[1], 1.f);  // terminated
  // Without it, the time limit truncates.
  Cheetah free;
  StepResult last;
  for (int t = 0; t < 1000; ++t) last = free.task->step(*free.state, a.data(), free.obs.data());
  EXPECT_TRUE(last.truncated);
  EXPECT_FALSE(last.terminated);
}

// Humanoid-v5's layout (the world body and the root's dofs left out) by names and skip; the centre
// of mass's position and velocity; no mj_rnePostConstraint where no term reads cfrc_ext.
TEST(TermsTask, PerBodyTermsTakeNamesAndTheCentreOfMassIsMuJoCos) {
  Shipped h("humanoid_sac.txtpb",
            "observation { term: \"cinert\" names: \".*\" }"
            "observation { term: \"cvel\" names: \"left_.*\" names: \"torso\" }"
            "observation { term: \"qfrc_actuator\" skip: 6 }"
            "observation { term: \"com_pos\" }"
            "observation { term: \"com_vel\" }",
            true);
  const mjModel* m = h.m();
  EXPECT_EQ(h.task->spec().obs_dim, 13 * 10 + 6 * 6 + 17 + 3 + 3);
  const int torso = mj_name2id(m, mjOBJ_BODY, "torso");
  std::vector<int> cvel_bodies;
  for (int b = 1; b < m->nbody; ++b)
    if (std::string(mj_id2name(m, mjOBJ_BODY, b)).rfind("left_", 0) == 0) cvel_bodies.push_back(b);
  cvel_bodies.push_back(torso);
  ASSERT_EQ(cvel_bodies.size(), 6u);
  mjData* copy = mj_makeData(m);
  for (int t = 0; t < 20; ++t) {
    const StepResult r = h.step(swing(17, t));
    if (r.terminated) break;
    const mjData* d = h.d();
    std::vector<double> want(d->cinert + 10, d->cinert + 10 * m->nbody);
    for (int b : cvel_bodies) want.insert(want.end(), d->cvel + 6 * b, d->cvel + 6 * b + 6);
    want.insert(want.end(), d->qfrc_actuator + 6, d->qfrc_actuator + m->nv);
    const auto com = mass_center_of(m, d);
    want.insert(want.end(), com.begin(), com.end());
    mj_copyData(copy, m, d);
    mj_subtreeVel(m, copy);  // the world body's subtree: the whole model
    want.insert(want.end(), copy->subtree_linvel, copy->subtree_linvel + 3);
    ASSERT_EQ(want.size(), h.obs.size());
    for (size_t i = 0; i < want.size(); ++i)
      EXPECT_NEAR(h.obs[i], want[i], 1e-5 * std::max(1.0, std::abs(want[i]))) << "step " << t << " entry " << i;
    EXPECT_GT(std::abs(copy->subtree_linvel[2]), 0) << "step " << t;  // falling: the check compares something
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(com[k], d->subtree_com[k], 1e-9);
    // No term reads cfrc_ext: mj_step leaves it as the reset did, though the feet touch the floor.
    for (int i = 0; i < 6 * m->nbody; ++i) EXPECT_EQ(d->cfrc_ext[i], 0) << "step " << t;
  }
  mj_deleteData(copy);
}

// com_progress along y and z: the centre of mass's displacement over the step, per second.
TEST(TermsTask, ComProgressIsTheCentreOfMassesVelocityOverTheStep) {
  Shipped h("humanoid_sac.txtpb",
            "reward { term: \"com_progress\" axis: 2 weight: 2 } reward { term: \"com_progress\" axis: 1 }");
  const mjModel* m = h.m();
  for (int t = 0; t < 15; ++t) {
    const auto before = mass_center_of(m, h.d());
    const StepResult r = h.step(swing(17, t));
    const mjData* d = h.d();
    const auto after = mass_center_of(m, d);
    double ctrl = 0;
    for (int i = 0; i < m->nu; ++i) ctrl += d->ctrl[i] * d->ctrl[i];
    const double v[3] = {(after[0] - before[0]) / 0.015, (after[1] - before[1]) / 0.015,
                         (after[2] - before[2]) / 0.015};
    EXPECT_NE(v[2], 0);
    EXPECT_NEAR(r.reward, 1.25 * v[0] + 5.0 - 0.1 * ctrl + 2 * v[2] + v[1], 1e-4) << "step " << t;
  }
}

// joint_pos ends the episode on the step a named joint's position leaves [min, max] (Hopper's
// healthy_angle_range on its rooty hinge; here the cheetah's).
TEST(TermsTask, JointPosEndsTheEpisodeWhenAJointLeavesItsRange) {
  Shipped c("half_cheetah_sac.txtpb", "termination { term: \"joint_pos\" names: \"rooty\" min: -0.2 max: 0.2 }");
  const mjModel* m = c.m();
  const int rooty = m->jnt_qposadr[mj_name2id(m, mjOBJ_JOINT, "rooty")];
  int t = 0;
  bool ended = false;
  for (; t < 500 && !ended; ++t) {
    const StepResult r = c.step(swing(6, t));
    const double q = c.d()->qpos[rooty];
    EXPECT_EQ(r.terminated, !(q >= -0.2 && q <= 0.2)) << "step " << t << " rooty " << q;
    ended = r.terminated;
  }
  EXPECT_TRUE(ended) << "rooty stayed within [-0.2, 0.2] for " << t << " steps";
  EXPECT_GT(t, 1);
  // Empty names: every hinge and slide joint, each against the same range.
  Shipped all("half_cheetah_sac.txtpb", "termination { term: \"joint_pos\" min: -0.5 max: 0.5 }");
  for (t = 0; t < 500; ++t) {
    const StepResult r = all.step(swing(6, t));
    bool out = false;
    for (int j = 0; j < all.m()->njnt; ++j) {
      const double q = all.d()->qpos[all.m()->jnt_qposadr[j]];
      out = out || !(q >= -0.5 && q <= 0.5);
    }
    EXPECT_EQ(r.terminated, out) << "step " << t;
    if (r.terminated) break;
  }
  EXPECT_LT(t, 500);
  EXPECT_GT(t, 0);
}

// state ends the episode on the step an entry of [qpos, qvel] (Gymnasium's state_vector()) from
// `skip` on leaves [min, max]; skip 9 on the cheetah (nq 9) reads qvel alone.
TEST(TermsTask, StateEndsTheEpisodeWhenAnEntryOfQposThenQvelLeavesItsRange) {
  for (int skip : {0, 2, 9}) {
    // The bound: halfway between the largest entry of the first two steps and that of the first
    // 200, from a run without the term (the same reset and actions give the same states).
    Shipped unbounded("half_cheetah_sac.txtpb");
    double early = 0, late = 0;
    for (int t = 0; t < 200; ++t) {
      unbounded.step(swing(6, t));
      const double x = largest_state(unbounded.m(), unbounded.d(), skip);
      if (t < 2) early = std::max(early, x);
      late = std::max(late, x);
    }
    ASSERT_GT(late, early) << "skip " << skip;
    const std::string text = std::to_string(0.5 * (early + late));
    const double bound = std::stod(text);
    Shipped c("half_cheetah_sac.txtpb", "termination { term: \"state\" skip: " + std::to_string(skip) + " min: -" +
                                            text + " max: " + text + " }");
    const mjModel* m = c.m();
    int t = 0;
    bool ended = false;
    for (; t < 200 && !ended; ++t) {
      const StepResult r = c.step(swing(6, t));
      const mjData* d = c.d();
      bool out = false;
      for (int i = skip; i < m->nq + m->nv; ++i) {
        const double v = i < m->nq ? d->qpos[i] : d->qvel[i - m->nq];
        out = out || !(v >= -bound && v <= bound);
      }
      EXPECT_EQ(r.terminated, out) << "skip " << skip << " step " << t;
      ended = r.terminated;
    }
    EXPECT_TRUE(ended) << "skip " << skip << ": the state stayed within +-" << bound << " for " << t << " steps";
    EXPECT_GT(t, 2) << "skip " << skip;
  }
  // skip counts entries of qpos and qvel together; no other termination term reads it.
  const std::string e = error_of(cheetah(kObs + "    termination { term: \"state\" skip: 19 }\n"));
  EXPECT_NE(e.find("field 'task.terms.termination[0].skip': expected 0..18 (the model's nq + nv), got 19"),
            std::string::npos)
      << e;
  const std::string j = error_of(cheetah(kObs + "    termination { term: \"height\" skip: 2 }\n"));
  EXPECT_NE(j.find("field 'task.terms.termination[0].skip': term 'height' does not read 'skip'"), std::string::npos)
      << j;
}

// Every registered term builds and gives finite values on the hexapod (a term added to the
// catalogue without a working function fails here).
TEST(TermsCatalogue, EveryTermBuildsAndStepsFinite) {
  const std::string base = kConfigs + "/hexapod_sac.txtpb";
  const auto with = [&](const std::string& extra) {
    auto cfg = load_config_file(base);
    config::TermsConfig more;
    EXPECT_TRUE(google::protobuf::TextFormat::ParseFromString(extra, &more)) << extra;
    cfg.mutable_task()->mutable_terms()->MergeFrom(more);
    return cfg.task().terms();
  };
  const auto params = [](const std::string& term, const char* list) {
    std::string p;
    const std::string l = list;
    if (l.find("names") != std::string::npos)
      p += term == "sensor"              ? " names: \"imu_gyro\""
           : term.rfind("joint", 0) == 0 ? " names: \"knee_.*\""
                                         : " names: \"shin_fl\"";
    if (l.find("target") != std::string::npos) p += " target: 0.9";
    if (l.find("expression") != std::string::npos) p += " expression: \"x_vel + imu_gyro_2\"";
    return p;
  };
  int n = 0;
  for (const auto& t : observation_terms()) {
    const auto cfg = with(std::string("observation { term: \"") + t.name + "\"" + params(t.name, t.params) + " }");
    TermsTask task(cfg);
    auto s = task.make_state();
    std::vector<float> obs(task.spec().obs_dim), a(task.spec().act_dim, 0.3f);
    task.reset(*s, 1, obs.data());
    for (int k = 0; k < 20; ++k) task.step(*s, a.data(), obs.data());
    for (float x : obs) EXPECT_TRUE(std::isfinite(x)) << t.name;
    ++n;
  }
  for (const auto& t : reward_terms()) {
    const auto cfg = with(std::string("reward { term: \"") + t.name + "\"" + params(t.name, t.params) + " }");
    TermsTask task(cfg);
    auto s = task.make_state();
    std::vector<float> obs(task.spec().obs_dim), a(task.spec().act_dim, 0.3f);
    task.reset(*s, 1, obs.data());
    for (int k = 0; k < 20; ++k) EXPECT_TRUE(std::isfinite(task.step(*s, a.data(), obs.data()).reward)) << t.name;
    ++n;
  }
  for (const auto& t : termination_terms()) {
    const auto cfg = with(std::string("termination { term: \"") + t.name + "\"" + params(t.name, t.params) + " }");
    TermsTask task(cfg);
    auto s = task.make_state();
    std::vector<float> obs(task.spec().obs_dim), a(task.spec().act_dim, 0.3f);
    task.reset(*s, 1, obs.data());
    for (int k = 0; k < 20; ++k) task.step(*s, a.data(), obs.data());
    ++n;
  }
  EXPECT_EQ(n, int(observation_terms().size() + reward_terms().size() + termination_terms().size()));
}

}  // namespace
}  // namespace farm::robots::terms
