// What the evaluator (evaluator.h) sends its requests over and takes its answers from: on the
// learner, the bus's two evaluation topics (bus_eval_channel()); in unit tests, a channel of their
// own, so that splitting, retries and merging run without processes or DDS.
#pragma once

#include <memory>
#include <string>

#include "farm.h"
#include "farm_config.pb.h"
#include "task_spec.h"

namespace farm {

namespace dds {
class Bus;
}

class EvalChannel {
 public:
  // Who wrote an answer: its participant (the key heartbeats bind a worker to, participant_key in
  // common/dds.h) and, under DDS Security, the name its certificate bears ("" without security).
  struct Writer {
    std::string participant, certificate_name;
  };
  virtual ~EvalChannel() = default;
  // Sends a request; false when it could not be written now (it is counted as asked anyway).
  virtual bool write(farm::msg::EvaluationRequest& request) = 0;
  // Takes the next answer that arrived, and who wrote it; false when none is waiting.
  virtual bool take(farm::msg::EvaluationAnswer& answer, Writer& writer) = 0;
  // Whether any worker's answer writer is matched (without one, nothing can arrive).
  virtual bool matched() const = 0;
  // Waits up to `seconds` for an answer.
  virtual void wait(double seconds) = 0;
  // Whether the bus runs under DDS Security: an evaluation is then confirmed by two workers.
  virtual bool secured() const = 0;
};

// The bus's evaluation topics; answers larger than what this experiment's evaluations can hold
// (max_eval_answer_bytes, eval_answer.h) are refused before memory is taken for them.
std::unique_ptr<EvalChannel> bus_eval_channel(farm::dds::Bus& bus, const config::ExperimentConfig& cfg,
                                              const robots::TaskSpec& spec);

}  // namespace farm
