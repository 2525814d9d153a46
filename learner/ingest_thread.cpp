#include "ingest_thread.h"

#include <chrono>

#include "meter.h"
#include "printable.h"

namespace farm {

IngestThread::IngestThread(farm::dds::Bus& bus, Ingest ingest, uint32_t max_sample_bytes, size_t capacity_bytes,
                           Log log, EventLog& events, Hold::Limits hold)
    : bus_(bus),
      ingest_(std::move(ingest)),
      // Samples over what this experiment's workers can send are refused before memory is taken for
      // them (docs/record/reliability.md, "size limits before memory").
      reader_(bus, farm::dds::kBatchTopic, "batch_reader", max_sample_bytes, {}, true),
      capacity_(std::max<size_t>(1, capacity_bytes)),
      log_(std::move(log)),
      events_(events),
      hold_(hold) {}

IngestThread::~IngestThread() {
  {
    std::lock_guard<std::mutex> lk(mu_);
    stop_ = true;
  }
  room_cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

void IngestThread::start(uint64_t version) {
  version_.store(version);
  {
    std::lock_guard<std::mutex> lk(mu_);
    env_steps_.store(ingest_.counters().env_steps);
    accepted_.store(ingest_.counters().ok);
    last_event_.ok = ingest_.counters().ok;
    last_event_.invalid = ingest_.counters().invalid;
  }
  thread_ = std::thread([this] { loop(); });
}

void IngestThread::loop() {
  for (;;) {
    {
      std::unique_lock<std::mutex> lk(mu_);
      if (!stop_ && queued_bytes_ >= capacity_) {
        full_waits_.fetch_add(1);
        room_cv_.wait(lk, [&] { return stop_ || queued_bytes_ < capacity_; });
      }
      if (stop_) return;
      // Samples refused before deserialization: too large for the reader's bound, or malformed
      // (bytes that do not decode as a TransitionBatch). Both count as invalid batches.
      const uint64_t malformed = reader_.malformed();
      if (const uint64_t refused = ingest_.count_refused_samples(reader_.refused() + malformed)) {
        const uint64_t fresh_malformed = malformed - malformed_seen_;
        malformed_seen_ = malformed;
        lk.unlock();
        if (refused > fresh_malformed) refused_for_size(refused - fresh_malformed);
        if (fresh_malformed > 0) refused_malformed(fresh_malformed);
      }
    }
    if (reader_.take(batch_, info_))
      offer();
    else
      reader_.wait(hold_.empty() ? 0.05 : 0.01);
    release_held();
    ingest_event(false);
  }
}

void IngestThread::refused_for_size(uint64_t n) {
  Caps& caps = caps_for("size");
  if (++caps.lines <= kMaxRefusalLines)
    log_("refused " + std::to_string(n) + " batch sample(s) larger than " + std::to_string(reader_.max_sample_bytes()) +
         " bytes serialized (the most this experiment's workers send) before deserialization");
  if (++caps.events <= kMaxRefusalEvents)
    events_.write("refusal", {{"what", "batch sample"},
                              {"count", n},
                              {"reason", "larger than " + std::to_string(reader_.max_sample_bytes()) + " bytes"}});
}

void IngestThread::refused_malformed(uint64_t n) {
  const std::string why = printable(reader_.last_malformed_reason(), 300);
  Caps& caps = caps_for("malformed");
  if (++caps.lines <= kMaxRefusalLines)
    log_("refused " + std::to_string(n) + " malformed batch sample(s) before deserialization: " + why);
  if (++caps.events <= kMaxRefusalEvents)
    events_.write("refusal", {{"what", "batch sample"}, {"count", n}, {"reason", "malformed"}, {"detail", why}});
}

namespace {

// What a held batch holds, for the hold's bound: its arrays and a little for the rest.
size_t held_bytes(const farm::msg::TransitionBatch& b) {
  return 4 * (b.observations().size() + b.actions().size() + b.rewards().size() + b.log_probs().size() +
              b.next_observations().size() + b.final_observations().size()) +
         b.terminated().size() + b.truncated().size() + 64 * b.episodes().size() + 256;
}

}  // namespace

void IngestThread::offer() {
  const Ingest::Key key{batch_.worker_id(), batch_.worker_session()};
  bool wait_for_announcement = hold_.holds(key);
  if (!wait_for_announcement) {
    std::lock_guard<std::mutex> lk(mu_);
    wait_for_announcement = ingest_.unannounced_opening(batch_);
  }
  if (!wait_for_announcement) {
    accept(batch_, info_);
    return;
  }
  const size_t bytes = held_bytes(batch_);
  Held h{std::move(batch_), info_};
  if (!hold_.hold(key, farm::dds::participant_key(info_.sample_identity.writer_guid()), bytes, now_seconds(), h)) {
    // No room: the session's held batches are decided now, then this one, in the order taken.
    hold_.release(key, [this](const Ingest::Key&, Held& held) { accept(held.batch, held.info); });
    accept(h.batch, h.info);
  }
  held_batches_.store(hold_.batches(), std::memory_order_relaxed);
}

void IngestThread::release_held() {
  if (hold_.empty()) return;
  hold_.release(
      now_seconds(),
      [this](const Ingest::Key& key) {
        std::lock_guard<std::mutex> lk(mu_);
        return !ingest_.announced(key).empty();
      },
      [this](const Ingest::Key&, Held& held) { accept(held.batch, held.info); });
  held_batches_.store(hold_.batches(), std::memory_order_relaxed);
}

bool IngestThread::accept(const farm::msg::TransitionBatch& batch, const eprosima::fastdds::dds::SampleInfo& info) {
  auto a = std::make_unique<AcceptedBatch>();
  // Under DDS Security a batch must come from the participant whose certificate bears its worker id.
  std::string writer, unnamed_why;
  const bool secure = !bus_.security_dir().empty();
  if (secure) writer = bus_.authenticated_name(info.sample_identity.writer_guid(), &unnamed_why);
  const std::string participant = farm::dds::participant_key(info.sample_identity.writer_guid());
  std::string why, retired_note;
  bool foreign = false;
  {
    std::lock_guard<std::mutex> lk(mu_);
    const uint64_t foreign_before = ingest_.counters().foreign, retired = ingest_.retired();
    why = ingest_.accept(batch, version_.load(), now_seconds(), a->rows, a->episodes, secure ? &writer : nullptr,
                         participant);
    if (ingest_.retired() > retired) retired_note = ingest_.last_retired();
    foreign = ingest_.counters().foreign > foreign_before;
    env_steps_.store(ingest_.counters().env_steps, std::memory_order_relaxed);
    accepted_.store(ingest_.counters().ok, std::memory_order_relaxed);
    if (why.empty()) {
      a->worker_id = batch.worker_id();
      a->policy_version = batch.policy_version();
      a->num_steps = int(batch.num_steps());
      a->num_envs = int(batch.num_envs());
      a->truncated.assign(batch.truncated().begin(), batch.truncated().end());
      a->log_probs.assign(batch.log_probs().begin(), batch.log_probs().end());
      queued_bytes_ += a->bytes();
      queue_.push_back(std::move(a));
    }
  }
  if (why.empty()) queued_cv_.notify_all();
  if (!retired_note.empty() && ++said_.retirements <= kMaxRefusalLines)
    log_("worker stream " + printable(retired_note, 200) + " retired to make room for " +
         printable(batch.worker_id(), 100) + "'s (at most " + std::to_string(Ingest::kMaxAccounts) + " streams open, " +
         std::to_string(Ingest::kMaxSessionsPerWorker) + " of one worker id)" +
         (said_.retirements == kMaxRefusalLines ? "; no more such lines (the summary counts them)" : ""));
  if (why.empty()) return true;
  if (foreign) {
    // Another experiment shares the domain: said once per experiment, not once per batch.
    if (said_.foreign.size() < 16 && said_.foreign.insert(batch.experiment_id()).second)
      log_("batches of experiment '" + printable(batch.experiment_id(), 100) +
           "' (another learner's, on this domain) are not used here; the summary counts them");
    return false;
  }
  // Under security: why the writer has no name (a revoked worker), and an identity token that names
  // another than the writer's certificate.
  const std::string detail = (writer.empty() && secure ? " (" + unnamed_why + ")" : "") +
                             token_note(info.sample_identity.writer_guid(), writer);
  // Capped per participant: one participant's refusals never use up another's lines and events.
  Caps& caps = caps_for("participant " + participant);
  if (++caps.lines <= kMaxRefusalLines)
    log_("rejected batch " + std::to_string(batch.sequence_number()) + " from " + printable(batch.worker_id(), 100) +
         ": " + why + detail);
  if (++caps.events <= kMaxRefusalEvents)
    events_.write("refusal", {{"what", "batch"},
                              {"worker_id", printable(batch.worker_id(), 100)},
                              {"sequence_number", batch.sequence_number()},
                              {"reason", printable(why, 500)},
                              {"detail", printable(detail, 500)}});
  return false;
}

// Where a participant's identity token names another than its writer's partition: said, since no
// one else checks it (Fast DDS 2.9.1 does not compare the token with the certificate).
std::string IngestThread::token_note(const eprosima::fastrtps::rtps::GUID_t& writer, const std::string& name) const {
  if (bus_.security_dir().empty() || name.empty()) return "";
  const std::string token = bus_.token_name(writer);
  return token == name ? "" : "; its participant's identity token claims '" + printable(token, 100) + "'";
}

void IngestThread::ingest_event(bool force) {
  const double now = now_seconds();
  if (!force && now - last_event_.t < kEventEveryS) return;
  IngestCounters c;
  size_t queued = 0, queued_bytes = 0;
  {
    std::lock_guard<std::mutex> lk(mu_);
    c = ingest_.counters();
    queued = queue_.size();
    queued_bytes = queued_bytes_;
  }
  if (!force && c.ok == last_event_.ok && c.invalid == last_event_.invalid) return;
  last_event_.t = now;
  last_event_.ok = c.ok;
  last_event_.invalid = c.invalid;
  events_.write("ingest", {{"batches_ok", c.ok},
                           {"held", held_batches_.load(std::memory_order_relaxed)},
                           {"batches_lost", c.lost},
                           {"batches_duplicate", c.duplicate},
                           {"batches_invalid", c.invalid},
                           {"env_steps", c.env_steps},
                           {"queued", queued},
                           {"queued_mib", double(queued_bytes) / (1 << 20)},
                           {"queue_full_waits", full_waits_.load()}});
}

size_t IngestThread::pop(size_t max, const std::function<void(AcceptedBatch&)>& take) {
  std::vector<std::unique_ptr<AcceptedBatch>> got;
  {
    std::lock_guard<std::mutex> lk(mu_);
    while (got.size() < max && !queue_.empty()) {
      queued_bytes_ -= queue_.front()->bytes();
      got.push_back(std::move(queue_.front()));
      queue_.pop_front();
    }
  }
  if (!got.empty()) room_cv_.notify_all();
  for (auto& a : got) take(*a);
  return got.size();
}

void IngestThread::wait(double seconds) {
  std::unique_lock<std::mutex> lk(mu_);
  queued_cv_.wait_for(lk, std::chrono::duration<double>(seconds), [&] { return !queue_.empty() || stop_; });
}

void IngestThread::settle(const std::function<void(AcceptedBatch&)>& take,
                          const std::function<void(const Ingest&)>& f) {
  {
    std::lock_guard<std::mutex> lk(mu_);
    while (!queue_.empty()) {
      queued_bytes_ -= queue_.front()->bytes();
      take(*queue_.front());
      queue_.pop_front();
    }
    f(ingest_);
  }
  room_cv_.notify_all();
}

void IngestThread::with_ingest(const std::function<void(Ingest&)>& f) {
  std::lock_guard<std::mutex> lk(mu_);
  f(ingest_);
  env_steps_.store(ingest_.counters().env_steps, std::memory_order_relaxed);
  accepted_.store(ingest_.counters().ok, std::memory_order_relaxed);
}

IngestCounters IngestThread::counters() const {
  std::lock_guard<std::mutex> lk(mu_);
  return ingest_.counters();
}

IngestThread::Caps& IngestThread::caps_for(const std::string& cause) {
  auto it = said_.by_cause.find(cause);
  if (it != said_.by_cause.end()) return it->second;
  // Past kMaxCauses causes, the new ones share one set of caps: the bound on lines and events holds.
  if (said_.by_cause.size() >= kMaxCauses) return said_.by_cause[""];
  return said_.by_cause[cause];
}

bool IngestThread::delivered(const std::string& worker_id, const std::string& participant) const {
  std::lock_guard<std::mutex> lk(mu_);
  for (const auto& [key, w] : ingest_.workers())
    if (w.worker_id == worker_id && w.received > 0 && !w.writer.empty() && w.writer == participant) return true;
  return false;
}

size_t IngestThread::queued() const {
  std::lock_guard<std::mutex> lk(mu_);
  return queue_.size();
}

size_t IngestThread::queued_bytes() const {
  std::lock_guard<std::mutex> lk(mu_);
  return queued_bytes_;
}

}  // namespace farm
