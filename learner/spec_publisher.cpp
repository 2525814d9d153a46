#include "spec_publisher.h"

#include "config.h"

#include <cstdio>
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
