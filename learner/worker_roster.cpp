#include "worker_roster.h"

#include <cstdio>

namespace farm {

namespace {
std::string seconds(double s) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.1f", s);
  return buf;
}
}  // namespace

bool WorkerRoster::heard(const farm::msg::WorkerStatus& s, double now) {
  if (!experiment_id_.empty() && s.experiment_id().empty() && !s.last_error().empty()) {
    note_rejection(s);
    return false;
  }
  if (!experiment_id_.empty() && s.experiment_id() != experiment_id_) {
    // A worker with no experiment yet (it waits for a spec) is not ours until it says so; one of
    // another experiment is noted once per experiment, so a shared domain shows in the log.
    if (!s.experiment_id().empty() && foreign_.size() < kMaxForeignNoted && foreign_.insert(s.experiment_id()).second)
      log_("heartbeats of another experiment, '" + s.experiment_id() + "' (worker " + s.worker_id() +
           "), are ignored: only workers of '" + experiment_id_ + "' count");
    return false;
  }
  View& v = views_[s.worker_id() + "#" + std::to_string(s.worker_session())];
  const std::string size = std::to_string(s.envs()) + " envs on " + std::to_string(s.threads()) + " threads";
  // A worker builds its environments once it has the spec: until then its heartbeats carry no size.
  if (v.seen == 0)
    log_("worker " + s.worker_id() + " on " + s.host() + " joined (session " + std::to_string(s.worker_session()) +
         ", " + (s.envs() > 0 ? size : std::string("waiting for the spec")) + ")");
  else if (s.envs() > 0 && v.last.envs() == 0)
    log_("worker " + s.worker_id() + " on " + s.host() + " runs " + size);
  if (v.dead) log_("worker " + s.worker_id() + " on " + s.host() + " is back after " + seconds(now - v.seen) + " s");
  if (!s.last_error().empty() && s.last_error() != v.last.last_error())
    log_("worker " + s.worker_id() + " reports: " + s.last_error());
  v.last = s;
  v.seen = now;
  v.dead = false;
  return true;
}

// A worker that could not run a spec has joined no experiment. Its error is the user's only clue
// (a worker built before a config field the learner's config sets, say), so it is logged when it
// names this learner's experiment: in the worker's words "cannot run experiment 'ID': ...", or, from
// an older worker, the spec's parse error "ExperimentSpec(ID):...". Once per worker id and error
// (a worker restarted over and over has a new session each time); the text is cut, its control
// characters replaced, and the lines bounded (a heartbeat is network input).
void WorkerRoster::note_rejection(const farm::msg::WorkerStatus& s) {
  const std::string& e = s.last_error();
  if (e.rfind("cannot run experiment '" + experiment_id_ + "'", 0) != 0 &&
      e.find("ExperimentSpec(" + experiment_id_ + ")") == std::string::npos)
    return;
  constexpr size_t kMaxError = 500;
  auto printable = [](std::string t) {
    for (char& c : t)
      if (static_cast<unsigned char>(c) < 0x20 || c == 0x7f) c = '?';
    return t;
  };
  const std::string text =
      printable(e.size() > kMaxError ? e.substr(0, kMaxError) + "... (" + std::to_string(e.size()) + " bytes)" : e);
  const std::string id = printable(s.worker_id().substr(0, 100));
  if (rejected_.size() >= kMaxRejectionsNoted || !rejected_.insert(id + "#" + text).second) return;
  log_("worker " + id + " on " + printable(s.host().substr(0, 100)) + " cannot join: " + text +
       (rejected_.size() == kMaxRejectionsNoted ? " (no more such lines)" : ""));
}

void WorkerRoster::check(double now) {
  for (auto& [k, v] : views_) {
    if (v.dead || v.last.state() == "finished" || now - v.seen < timeout_) continue;
    v.dead = true;
    log_("worker " + v.last.worker_id() + " on " + v.last.host() + " silent for " + seconds(now - v.seen) +
         " s: marked dead; going on with " + std::to_string(live_count(now)) + " workers");
  }
}

bool WorkerRoster::live(const View& v, double now) const {
  return !v.dead && now - v.seen < timeout_ && v.last.state() != "finished";
}

int WorkerRoster::live_count(double now) const {
  int n = 0;
  for (const auto& [k, v] : views_) n += live(v, now);
  return n;
}

}  // namespace farm
