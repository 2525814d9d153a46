#include "spec_publisher.h"

#include "config.h"

#include <cstdio>
#include <stdexcept>
#include <string>

namespace farm {

SpecPublisher::SpecPublisher(farm::dds::Bus& bus, const config::ExperimentConfig& cfg, int obs_dim, int act_dim)
    : out_(bus, farm::dds::kSpecTopic, "latest_writer") {
  spec_.experiment_id(cfg.experiment_id());
  // Files the config names for the process that builds the task to write are not the workers'
  // business (a worker refuses a spec that names one), and the learner builds no task: said once.
  for (const std::string& field : output_path_fields(cfg))
    std::printf(
        "[learner] %s names a file that a program building the task writes (farm-play, "
        "farm-mclari-sweep, farm-mclari-eval); the learner builds no task, so it is not written here, "
        "and it is not sent to the workers\n",
        field.c_str());
  config::ExperimentConfig sent = cfg;
  clear_output_paths(&sent);
  spec_.config_text(config_to_text(sent));
  spec_.task_name(cfg.task().name());
  spec_.obs_dim(obs_dim);
  spec_.act_dim(act_dim);
  spec_.steps_per_batch(cfg.worker().steps_per_batch());
  spec_.max_batches_per_version(cfg.worker().max_batches_per_version());
  spec_.seed(cfg.seed());
  spec_.learner_session(farm::dds::random_session_id());
  // Workers refuse a larger spec before reading it (dds::kMaxSpecBytes): said here, at the start.
  const uint64_t bytes = spec_.config_text().size() + spec_.experiment_id().size() + spec_.task_name().size() + 4096;
  if (bytes > farm::dds::kMaxSpecBytes)
    throw std::runtime_error("the experiment's spec would be " + std::to_string(bytes) +
                             " bytes on the bus, more than the " + std::to_string(farm::dds::kMaxSpecBytes) +
                             " a worker takes (a model's files count in it: task.terms.max_model_bytes)");
}

void SpecPublisher::publish(bool finished) {
  spec_.finished(finished);
  out_.write(spec_);
}

void SpecPublisher::republish_if_due(double now) {
  if (spec_.finished() || now - last_ < farm::dds::kSpecRepublishSeconds) return;
  publish(false);
  last_ = now;
}

}  // namespace farm
