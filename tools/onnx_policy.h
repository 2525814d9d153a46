// A worker's policy (normalizer, network, deterministic action head) as an ONNX model: the graph
// computes from "obs" [N, obs_dim] what Policy::act computes with deterministic = true, with
// operators of ONNX opset 10, which OpenCV's DNN module and the other common runtimes read.
#pragma once

#include <onnx/onnx_pb.h>

#include <string>
#include <utility>
#include <vector>

#include "mlp.h"

namespace farm::tools {

// ONNX opset and IR version the models are written with (opset 10 keeps Clip's bounds as
// attributes, the form OpenCV 4.6 reads; IR 5 is the version that opset came with).
inline constexpr int kOnnxOpset = 10;
inline constexpr int kOnnxIrVersion = 5;

// The model's graph outputs: "action" [N, act_dim] float in [-1, 1] (SAC: tanh of the mean
// half of the network's output; PPO: the mean clipped to [-1, 1]); for DQN "action" [N, 1] int64,
// the argmax over "q_values" [N, num_actions], the network's output, also an output.
inline constexpr const char* kInputName = "obs";
inline constexpr const char* kActionName = "action";
inline constexpr const char* kQValuesName = "q_values";

// Builds the model; metadata goes to metadata_props in the order given. Throws
// std::invalid_argument when the policy's sizes are inconsistent (as Policy's constructor does).
onnx::ModelProto policy_to_onnx(const PolicyParams& p, const std::vector<std::pair<std::string, std::string>>& metadata,
                                const std::string& doc);

// onnx's own checker (libonnx); throws std::runtime_error with its message when it rejects the model.
void check_onnx_model(const onnx::ModelProto& model);

}  // namespace farm::tools
