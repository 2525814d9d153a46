// farm-export's ONNX graph (tools/onnx_policy.*): the operators and tensors of each head and
// activation, the layout of the weights, the metadata, onnx's checker accepting what is built and
// rejecting a broken graph, and the worker's consistency checks applied before anything is built.
#include <gtest/gtest.h>

#include <cstring>
#include <stdexcept>
#include <string>
#include <vector>

#include "onnx_policy.h"

namespace farm::tools {
namespace {

std::vector<std::string> ops(const onnx::ModelProto& m) {
  std::vector<std::string> v;
  for (const auto& n : m.graph().node()) v.push_back(n.op_type());
  return v;
}

const onnx::TensorProto& initializer(const onnx::ModelProto& m, const std::string& name) {
  for (const auto& t : m.graph().initializer())
    if (t.name() == name) return t;
  throw std::runtime_error("no initializer " + name);
}

std::vector<float> floats(const onnx::TensorProto& t) {
  std::vector<float> v(t.raw_data().size() / sizeof(float));
  std::memcpy(v.data(), t.raw_data().data(), v.size() * sizeof(float));
  return v;
}

// 2-3-4 with parameters 0, 1, 2, ... in the flat order (W1 [3x2], b1 [3], W2 [4x3], b2 [4]).
PolicyParams sac_policy() {
  PolicyParams p;
  p.version = 42;
  p.head = PolicyHead::kSquashedGaussian;
  p.layout = {{2, 3, 4}, Activation::kRelu};
  for (size_t i = 0; i < p.layout.num_params(); ++i) p.params.push_back(float(i));
  p.obs_mean = {0.5f, -1.f};
  p.obs_std = {2.f, 4.f};
  return p;
}

TEST(OnnxPolicy, SacKeepsTheMeanHalfOfTheLastLayerAndNormalizes) {
  const auto m = policy_to_onnx(sac_policy(), {{"task", "pendulum"}, {"algorithm", "sac"}}, "doc");
  EXPECT_NO_THROW(check_onnx_model(m));
  EXPECT_EQ(ops(m), (std::vector<std::string>{"Sub", "Div", "Gemm", "Relu", "Gemm", "Tanh"}));
  EXPECT_EQ(m.opset_import(0).version(), kOnnxOpset);
  EXPECT_EQ(m.model_version(), 42);
  ASSERT_EQ(m.graph().input_size(), 1);
  EXPECT_EQ(m.graph().input(0).name(), "obs");
  EXPECT_EQ(m.graph().input(0).type().tensor_type().shape().dim(0).dim_param(), "N");
  EXPECT_EQ(m.graph().input(0).type().tensor_type().shape().dim(1).dim_value(), 2);
  ASSERT_EQ(m.graph().output_size(), 1);
  EXPECT_EQ(m.graph().output(0).name(), "action");
  EXPECT_EQ(m.graph().output(0).type().tensor_type().shape().dim(1).dim_value(), 2);  // act_dim = 4 / 2
  EXPECT_EQ(floats(initializer(m, "obs_std")), (std::vector<float>{2.f, 4.f}));
  // Layer 0 whole: W [3x2] = 0..5, b = 6..8. Layer 1: the first 2 of its 4 rows, W 9..14, b 21, 22.
  EXPECT_EQ(floats(initializer(m, "layer0.weight")), (std::vector<float>{0, 1, 2, 3, 4, 5}));
  EXPECT_EQ(floats(initializer(m, "layer0.bias")), (std::vector<float>{6, 7, 8}));
  EXPECT_EQ(floats(initializer(m, "layer1.weight")), (std::vector<float>{9, 10, 11, 12, 13, 14}));
  EXPECT_EQ(floats(initializer(m, "layer1.bias")), (std::vector<float>{21, 22}));
  ASSERT_EQ(m.metadata_props_size(), 2);
  EXPECT_EQ(m.metadata_props(0).key(), "task");
  EXPECT_EQ(m.metadata_props(1).value(), "sac");
}

TEST(OnnxPolicy, PpoClipsTheMeanAndDqnTakesTheArgmax) {
  PolicyParams ppo = sac_policy();
  ppo.head = PolicyHead::kGaussian;
  ppo.layout.activation = Activation::kTanh;
  ppo.log_std = {0.f, 0.f, 0.f, 0.f};
  ppo.obs_mean.clear();
  ppo.obs_std.clear();
  const auto pm = policy_to_onnx(ppo, {}, "");
  EXPECT_NO_THROW(check_onnx_model(pm));
  EXPECT_EQ(ops(pm), (std::vector<std::string>{"Gemm", "Tanh", "Gemm", "Clip"}));
  EXPECT_EQ(pm.graph().output(0).type().tensor_type().shape().dim(1).dim_value(), 4);

  PolicyParams dqn = sac_policy();
  dqn.head = PolicyHead::kDiscreteQ;
  dqn.obs_mean.clear();
  dqn.obs_std.clear();
  const auto dm = policy_to_onnx(dqn, {}, "");
  EXPECT_NO_THROW(check_onnx_model(dm));
  EXPECT_EQ(ops(dm), (std::vector<std::string>{"Gemm", "Relu", "Gemm", "ArgMax"}));
  ASSERT_EQ(dm.graph().output_size(), 2);
  EXPECT_EQ(dm.graph().output(0).name(), "action");
  EXPECT_EQ(dm.graph().output(0).type().tensor_type().elem_type(), onnx::TensorProto::INT64);
  EXPECT_EQ(dm.graph().output(1).name(), "q_values");
  EXPECT_EQ(dm.graph().output(1).type().tensor_type().shape().dim(1).dim_value(), 4);
  EXPECT_EQ(floats(initializer(dm, "layer1.bias")), (std::vector<float>{21, 22, 23, 24}));  // all four rows
}

// ELU hidden layers (PPO's "elu", legged_gym's A1 network) are Elu nodes with alpha 1, the
// worker's x > 0 ? x : exp(x) - 1; the node after every hidden layer, none after the last.
TEST(OnnxPolicy, EluLayersAreEluNodesWithAlphaOne) {
  PolicyParams p;
  p.head = PolicyHead::kGaussian;
  p.layout = {{2, 3, 3, 2}, Activation::kElu};
  p.params.assign(p.layout.num_params(), 0.5f);
  p.log_std = {0.f, 0.f};
  const auto m = policy_to_onnx(p, {}, "");
  EXPECT_NO_THROW(check_onnx_model(m));
  EXPECT_EQ(ops(m), (std::vector<std::string>{"Gemm", "Elu", "Gemm", "Elu", "Gemm", "Clip"}));
  for (const auto& n : m.graph().node()) {
    if (n.op_type() != "Elu") continue;
    ASSERT_EQ(n.attribute_size(), 1) << n.name();
    EXPECT_EQ(n.attribute(0).name(), "alpha");
    EXPECT_EQ(n.attribute(0).type(), onnx::AttributeProto::FLOAT);
    EXPECT_EQ(n.attribute(0).f(), 1.f);
  }
  EXPECT_EQ(m.graph().node(1).input(0), "layer0.linear");
  EXPECT_EQ(m.graph().node(2).input(0), m.graph().node(1).output(0));  // the next Gemm reads the Elu's output
  // An activation the worker does not know is refused before any graph is built.
  p.layout.activation = static_cast<Activation>(7);
  EXPECT_THROW(policy_to_onnx(p, {}, ""), std::invalid_argument);
}

TEST(OnnxPolicy, TheCheckerRejectsABrokenGraph) {
  auto m = policy_to_onnx(sac_policy(), {}, "");
  m.mutable_graph()->mutable_initializer()->RemoveLast();  // layer1.bias: a Gemm input nobody makes
  try {
    check_onnx_model(m);
    FAIL() << "the checker accepted a graph with an undefined input";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("onnx checker rejects the model"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("layer1.bias"), std::string::npos) << e.what();
  }
}

TEST(OnnxPolicy, InconsistentPoliciesAreRefused) {
  PolicyParams p = sac_policy();
  p.params.pop_back();
  EXPECT_THROW(policy_to_onnx(p, {}, ""), std::invalid_argument);
  p = sac_policy();
  p.obs_std[1] = 0.f;
  EXPECT_THROW(policy_to_onnx(p, {}, ""), std::invalid_argument);
}

}  // namespace
}  // namespace farm::tools
