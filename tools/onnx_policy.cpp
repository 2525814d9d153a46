// The ONNX graph of a worker's deterministic policy: Sub/Div for the observation normalizer, one
// Gemm (+ Relu, Tanh or Elu) per layer, then the action head (Tanh, Clip or ArgMax).
#include "onnx_policy.h"

#include <onnx/checker.h>

#include <stdexcept>

namespace farm::tools {

namespace {

void add_initializer(onnx::GraphProto& g, const std::string& name, const std::vector<int64_t>& dims,
                     const float* data) {
  onnx::TensorProto* t = g.add_initializer();
  t->set_name(name);
  t->set_data_type(onnx::TensorProto::FLOAT);
  int64_t n = 1;
  for (int64_t d : dims) {
    t->add_dims(d);
    n *= d;
  }
  // raw_data is little-endian IEEE floats, the layout of this host's floats (x86-64, aarch64).
  t->set_raw_data(reinterpret_cast<const char*>(data), size_t(n) * sizeof(float));
}

onnx::NodeProto* add_node(onnx::GraphProto& g, const std::string& op, const std::vector<std::string>& inputs,
                          const std::string& output) {
  onnx::NodeProto* n = g.add_node();
  n->set_op_type(op);
  n->set_name(output);
  for (const auto& i : inputs) n->add_input(i);
  n->add_output(output);
  return n;
}

void set_int(onnx::NodeProto* n, const std::string& name, int64_t v) {
  onnx::AttributeProto* a = n->add_attribute();
  a->set_name(name);
  a->set_type(onnx::AttributeProto::INT);
  a->set_i(v);
}

void set_float(onnx::NodeProto* n, const std::string& name, float v) {
  onnx::AttributeProto* a = n->add_attribute();
  a->set_name(name);
  a->set_type(onnx::AttributeProto::FLOAT);
  a->set_f(v);
}

// A graph input or output of shape [N, cols] (N: the batch, named "N").
void set_value_info(onnx::ValueInfoProto* v, const std::string& name, onnx::TensorProto::DataType type, int64_t cols) {
  v->set_name(name);
  onnx::TypeProto::Tensor* t = v->mutable_type()->mutable_tensor_type();
  t->set_elem_type(type);
  t->mutable_shape()->add_dim()->set_dim_param("N");
  t->mutable_shape()->add_dim()->set_dim_value(cols);
}

// The hidden layers' activation on y as the node "NAME.relu", ".tanh" or ".elu"; returns its output.
std::string add_activation(onnx::GraphProto& g, Activation a, const std::string& y, const std::string& name) {
  switch (a) {
    case Activation::kRelu:
      add_node(g, "Relu", {y}, name + ".relu");
      return name + ".relu";
    case Activation::kTanh:
      add_node(g, "Tanh", {y}, name + ".tanh");
      return name + ".tanh";
    case Activation::kElu:
      // x > 0 ? x : alpha * (exp(x) - 1), alpha 1 as the worker's kernel and torch::elu.
      set_float(add_node(g, "Elu", {y}, name + ".elu"), "alpha", 1.f);
      return name + ".elu";
  }
  throw std::invalid_argument("onnx export: unknown activation " + std::to_string(int(a)));
}

}  // namespace

onnx::ModelProto policy_to_onnx(const PolicyParams& p, const std::vector<std::pair<std::string, std::string>>& metadata,
                                const std::string& doc) {
  const Policy check(p);  // the worker's own consistency checks (sizes, normalizer, head)
  const auto& sizes = p.layout.sizes;
  const int obs_dim = sizes.front(), out_dim = sizes.back(), act_dim = check.act_dim();
  const size_t layers = sizes.size() - 1;

  onnx::ModelProto m;
  m.set_ir_version(kOnnxIrVersion);
  m.set_producer_name("farm-export");
  m.set_model_version(int64_t(p.version));
  m.set_doc_string(doc);
  onnx::OperatorSetIdProto* opset = m.add_opset_import();
  opset->set_domain("");
  opset->set_version(kOnnxOpset);
  for (const auto& [key, value] : metadata) {
    onnx::StringStringEntryProto* e = m.add_metadata_props();
    e->set_key(key);
    e->set_value(value);
  }

  onnx::GraphProto& g = *m.mutable_graph();
  g.set_name("farm_policy");
  set_value_info(g.add_input(), kInputName, onnx::TensorProto::FLOAT, obs_dim);
  std::string x = kInputName;
  if (!p.obs_mean.empty()) {
    // (obs - mean) / std, in the worker's order of operations.
    add_initializer(g, "obs_mean", {obs_dim}, p.obs_mean.data());
    add_initializer(g, "obs_std", {obs_dim}, p.obs_std.data());
    add_node(g, "Sub", {x, "obs_mean"}, "obs_centered");
    add_node(g, "Div", {"obs_centered", "obs_std"}, "obs_normalized");
    x = "obs_normalized";
  }
  const float* w = p.params.data();
  for (size_t l = 0; l < layers; ++l) {
    const int in = sizes[l], out = sizes[l + 1];
    const float* b = w + size_t(out) * in;
    const bool last = l + 1 == layers;
    // SAC's deterministic action reads only the mean half of the last layer ([mean | log_std]):
    // the model keeps those rows, each the same dot product the worker computes.
    const int rows = last && p.head == PolicyHead::kSquashedGaussian ? act_dim : out;
    const std::string name = "layer" + std::to_string(l);
    add_initializer(g, name + ".weight", {rows, in}, w);
    add_initializer(g, name + ".bias", {rows}, b);
    const std::string y = !last ? name + ".linear" : p.head == PolicyHead::kDiscreteQ ? kQValuesName : "mean";
    set_int(add_node(g, "Gemm", {x, name + ".weight", name + ".bias"}, y), "transB", 1);
    x = y;
    if (!last) x = add_activation(g, p.layout.activation, y, name);
    w = b + out;
  }
  switch (p.head) {
    case PolicyHead::kSquashedGaussian:
      add_node(g, "Tanh", {x}, kActionName);
      set_value_info(g.add_output(), kActionName, onnx::TensorProto::FLOAT, act_dim);
      break;
    case PolicyHead::kGaussian: {
      onnx::NodeProto* clip = add_node(g, "Clip", {x}, kActionName);
      set_float(clip, "min", -1.f);
      set_float(clip, "max", 1.f);
      set_value_info(g.add_output(), kActionName, onnx::TensorProto::FLOAT, act_dim);
      break;
    }
    case PolicyHead::kDiscreteQ: {
      // ArgMax takes the first of equal maxima, as std::max_element does in the worker.
      onnx::NodeProto* argmax = add_node(g, "ArgMax", {x}, kActionName);
      set_int(argmax, "axis", 1);
      set_int(argmax, "keepdims", 1);
      set_value_info(g.add_output(), kActionName, onnx::TensorProto::INT64, 1);
      set_value_info(g.add_output(), kQValuesName, onnx::TensorProto::FLOAT, out_dim);
      break;
    }
  }
  return m;
}

void check_onnx_model(const onnx::ModelProto& model) {
  try {
    onnx::checker::check_model(model);
  } catch (const onnx::checker::ValidationError& e) {
    throw std::runtime_error(std::string("onnx checker rejects the model: ") + e.what());
  }
}

}  // namespace farm::tools
