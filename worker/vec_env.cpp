#include "vec_env.h"

#include <algorithm>
#include <stdexcept>
#include <string>

namespace farm {

EpisodeRecord& EpisodeEnds::add(int obs_dim, float** final_obs) {
  if (size_ == 0) obs_dim_ = obs_dim;
  if (size_ == int(records_.size())) records_.emplace_back();
  const size_t need = size_t(size_ + 1) * obs_dim_;
  if (final_obs_.size() < need) final_obs_.resize(std::max(need, 2 * final_obs_.size()));
  *final_obs = final_obs_.data() + size_t(size_) * obs_dim_;
  return records_[size_++];
}

VecEnv::VecEnv(std::shared_ptr<const robots::Task> task, int num_envs, uint64_t seed, uint64_t first_index)
    : task_(std::move(task)), first_index_(first_index) {
  if (!task_) throw std::invalid_argument("VecEnv: no task");
  if (num_envs <= 0) {
    throw std::invalid_argument("VecEnv: num_envs must be > 0, got " + std::to_string(num_envs));
  }
  const robots::TaskSpec& s = task_->spec();
  obs_dim_ = s.obs_dim;
  act_dim_ = s.act_dim;
  num_metrics_ = int(s.metric_names.size());
  states_.reserve(num_envs);
  for (int i = 0; i < num_envs; ++i) states_.push_back(task_->make_state());
  reseed(seed);
  obs_.assign(size_t(num_envs) * obs_dim_, 0.f);
}

void VecEnv::reseed(uint64_t seed) {
  seed_state_.resize(states_.size());
  for (size_t i = 0; i < states_.size(); ++i) seed_state_[i] = mix_seed(seed, first_index_ + uint64_t(i));
}

void VecEnv::reseed_env(int env, uint64_t seed, uint64_t stream) {
  seed_state_.at(size_t(env)) = mix_seed(seed, stream);
}

void VecEnv::reset(int env) {
  task_->reset(*states_[env], splitmix64(seed_state_[env]), obs_.data() + size_t(env) * obs_dim_);
}

void VecEnv::reset_in_condition(int env, int condition) {
  task_->reset_in_condition(*states_[env], splitmix64(seed_state_[env]), condition,
                            obs_.data() + size_t(env) * obs_dim_);
}

void VecEnv::reset_all() {
  for (int i = 0; i < num_envs(); ++i) reset(i);
}

void VecEnv::step_range(int begin, int end, const float* actions, float* rewards, uint8_t* terminated,
                        uint8_t* truncated, EpisodeEnds& ends) {
  for (int i = begin; i < end; ++i) {
    robots::TaskState& s = *states_[i];
    float* o = obs_.data() + size_t(i) * obs_dim_;
    const robots::StepResult r = task_->step(s, actions + size_t(i) * act_dim_, o);
    rewards[i] = r.reward;
    terminated[i] = r.terminated;
    truncated[i] = r.truncated && !r.terminated;
    if (!r.terminated && !r.truncated) continue;

    float* final_obs = nullptr;
    EpisodeRecord& rec = ends.add(obs_dim_, &final_obs);
    std::copy(o, o + obs_dim_, final_obs);
    rec.env = i;
    rec.episode_return = float(s.episode_return);
    rec.length = s.step;
    rec.terminated = r.terminated;
    rec.metrics.resize(num_metrics_);
    if (num_metrics_ > 0) task_->episode_metrics(s, rec.metrics.data());
    reset(i);
  }
}

}  // namespace farm
