// The evaluator's channel over the bus (eval_channel.h).
#include "eval_channel.h"

#include <algorithm>

#include "dds.h"
#include "eval_answer.h"

namespace farm {

namespace {

class BusEvalChannel : public EvalChannel {
 public:
  BusEvalChannel(farm::dds::Bus& bus, const config::ExperimentConfig& cfg, const robots::TaskSpec& spec)
      : bus_(bus),
        out_(bus, farm::dds::kEvalRequestTopic, "batch_writer"),
        in_(bus, farm::dds::kEvalAnswerTopic, "batch_reader",
            max_eval_answer_bytes(cfg.experiment_id().size(),
                                  std::max(cfg.eval().episodes(), cfg.eval().final_episodes()),
                                  int(spec.metric_names.size()))) {}

  bool write(farm::msg::EvaluationRequest& request) override { return out_.write(request); }
  bool take(farm::msg::EvaluationAnswer& answer, Writer& writer) override {
    if (!in_.take(answer, info_)) return false;
    const auto& guid = info_.sample_identity.writer_guid();
    writer.participant = farm::dds::participant_key(guid);
    writer.certificate_name = secured() ? bus_.authenticated_name(guid) : std::string();
    return true;
  }
  bool matched() const override { return in_.matched() > 0; }
  void wait(double seconds) override { in_.wait(seconds); }
  bool secured() const override { return !bus_.security_dir().empty(); }

 private:
  farm::dds::Bus& bus_;
  farm::dds::Writer<farm::msg::EvaluationRequest, farm::msg::EvaluationRequestPubSubType> out_;
  farm::dds::Reader<farm::msg::EvaluationAnswer, farm::msg::EvaluationAnswerPubSubType> in_;
  eprosima::fastdds::dds::SampleInfo info_;
};

}  // namespace

std::unique_ptr<EvalChannel> bus_eval_channel(farm::dds::Bus& bus, const config::ExperimentConfig& cfg,
                                              const robots::TaskSpec& spec) {
  return std::make_unique<BusEvalChannel>(bus, cfg, spec);
}

}  // namespace farm
