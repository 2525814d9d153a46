// The roster on its own thread (roster_thread.h).
#include "roster_thread.h"

#include <algorithm>
#include <chrono>

#include "meter.h"
#include "printable.h"

namespace farm {

RosterThread::RosterThread(farm::dds::Bus& bus, WorkerRoster roster, Log log, EventLog& events)
    : bus_(bus),
      log_(std::move(log)),
      events_(events),
      roster_(std::move(roster)),
      // A heartbeat over the bound is refused before memory is taken for it.
      reader_(bus, farm::dds::kWorkerStatusTopic, "status_reader", farm::dds::kMaxStatusBytes,
              [this](eprosima::fastdds::dds::DataReader* r) {
                if (!started_.load() || stop_.load()) return;
                // This runs under the reader's own lock, which a taker holding take_mu_ waits for:
                // where another takes, it takes this heartbeat too, once this returns.
                std::unique_lock<std::mutex> taking(take_mu_, std::try_to_lock);
                if (taking.owns_lock()) take_all(r);
              }) {}

RosterThread::~RosterThread() {
  stop_ = true;
  if (thread_.joinable()) thread_.join();
}

void RosterThread::start() {
  started_ = true;
  thread_ = std::thread([this] { loop(); });
}

void RosterThread::loop() {
  double last_check = 0;
  while (!stop_) {
    take_pending();  // what the listener did not take: what arrived before start()
    std::this_thread::sleep_for(std::chrono::duration<double>(kLoopEveryS));
    const double now = now_seconds();
    if (now - last_check >= kCheckEveryS) {
      last_check = now;
      std::lock_guard<std::mutex> lk(mu_);
      roster_.check(now);
    }
    const uint64_t refused = refused_for_name_.load();
    if (refused > refused_noted_ && refusal_notes_ < kMaxRefusalNotes) {
      ++refusal_notes_;
      std::string last;
      {
        std::lock_guard<std::mutex> lk(mu_);  // a taker writes it
        last = refused_last_;
      }
      log_("ignored " + std::to_string(refused - refused_noted_) +
           " heartbeat(s) whose worker id is not the certificate name of the participant that wrote them (last: " +
           last + ")");
      events_.write("refusal", {{"what", "heartbeat"},
                                {"count", refused - refused_noted_},
                                {"reason", "worker id is not the certificate name of the participant that wrote it"},
                                {"last", last}});
      refused_noted_ = refused;
    }
    const uint64_t over_rate = refused_for_rate_.load();
    // At most one line a second: a flood's refusals are told as sums, over its first 20 s.
    if (over_rate > rate_noted_ && rate_notes_ < kMaxRefusalNotes && now - rate_noted_at_ >= 1.0) {
      ++rate_notes_;
      rate_noted_at_ = now;
      const std::string why = "past " + std::to_string(int(kMaxBeatsPerSecond)) + " a second from one participant";
      log_("ignored " + std::to_string(over_rate - rate_noted_) + " heartbeat(s) " + why);
      events_.write("refusal", {{"what", "heartbeat"}, {"count", over_rate - rate_noted_}, {"reason", why}});
      rate_noted_ = over_rate;
    }
    const uint64_t oversized = reader_.refused();
    if (oversized > oversized_noted_ && refusal_notes_ < kMaxRefusalNotes) {
      ++refusal_notes_;
      const std::string why = "larger than " + std::to_string(farm::dds::kMaxStatusBytes) + " bytes";
      log_("refused " + std::to_string(oversized - oversized_noted_) + " heartbeat(s) " + why);
      events_.write("refusal",
                    {{"what", "heartbeat sample"}, {"count", oversized - oversized_noted_}, {"reason", why}});
      oversized_noted_ = oversized;
    }
  }
}

void RosterThread::take_pending() {
  std::lock_guard<std::mutex> taking(take_mu_);
  take_all(reader_.dds_reader());
}

void RosterThread::take_all(eprosima::fastdds::dds::DataReader* reader) {
  farm::msg::WorkerStatus s;
  eprosima::fastdds::dds::SampleInfo info;
  while (decltype(reader_)::take_from(reader, s, info)) {
    const double now = now_seconds();
    const std::string participant = farm::dds::participant_key(info.sample_identity.writer_guid());
    if (!within_share(participant, now)) {
      refused_for_rate_.fetch_add(1);
      continue;
    }
    // Under DDS Security, as for batches: only from the participant whose certificate bears the
    // worker id (no invented workers in the roster).
    if (!bus_.security_dir().empty()) {
      std::string why;
      const std::string by = bus_.authenticated_name(info.sample_identity.writer_guid(), &why);
      if (by != s.worker_id()) {
        refused_for_name_.fetch_add(1);
        std::string last = "'" + printable(s.worker_id(), 100) + "' from '" + printable(by, 100) + "'" +
                           (by.empty() ? ": " + why : "");
        std::lock_guard<std::mutex> lk(mu_);
        refused_last_ = std::move(last);
        continue;
      }
    }
    std::lock_guard<std::mutex> lk(mu_);
    if (roster_.heard(s, now, participant) && first_heard_.load() == 0) first_heard_.store(now);
  }
}

bool RosterThread::within_share(const std::string& participant, double now) {
  auto it = buckets_.find(participant);
  if (it == buckets_.end()) {
    if (buckets_.size() >= kMaxRatedParticipants) {
      // Full: those whose share has filled up again (silent for a while) go first; else the fullest.
      auto out = buckets_.begin();
      for (auto j = buckets_.begin(); j != buckets_.end(); ++j)
        if (j->second.tokens + (now - j->second.at) * kMaxBeatsPerSecond >
            out->second.tokens + (now - out->second.at) * kMaxBeatsPerSecond)
          out = j;
      buckets_.erase(out);
    }
    it = buckets_.emplace(participant, Bucket{kBeatBurst, now}).first;
  }
  Bucket& b = it->second;
  b.tokens = std::min(kBeatBurst, b.tokens + (now - b.at) * kMaxBeatsPerSecond);
  b.at = now;
  if (b.tokens < 1) return false;
  b.tokens -= 1;
  return true;
}

std::vector<RosterThread::Worker> RosterThread::workers() const {
  const double now = now_seconds();
  std::lock_guard<std::mutex> lk(mu_);
  std::vector<Worker> out;
  out.reserve(roster_.views().size());
  for (const auto& [key, v] : roster_.views()) out.push_back({key, v, roster_.live(v, now)});
  return out;
}

std::optional<RosterThread::Worker> RosterThread::find(const std::string& key) const {
  const double now = now_seconds();
  std::lock_guard<std::mutex> lk(mu_);
  const auto it = roster_.views().find(key);
  if (it == roster_.views().end()) return std::nullopt;
  return Worker{key, it->second, roster_.live(it->second, now)};
}

int RosterThread::live_count() const {
  const double now = now_seconds();
  std::lock_guard<std::mutex> lk(mu_);
  return roster_.live_count(now);
}

}  // namespace farm
