#include "worker_roster.h"

#include <cstdio>

#include "printable.h"

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
      log_("heartbeats of another experiment, '" + printable(s.experiment_id()) + "' (worker " +
           printable(s.worker_id()) + "), are ignored: only workers of '" + experiment_id_ + "' count");
    return false;
  }
  View& v = views_[s.worker_id() + "#" + std::to_string(s.worker_session())];
  const std::string size = std::to_string(s.envs()) + " envs on " + std::to_string(s.threads()) + " threads";
  // A worker builds its environments once it has the spec: until then its heartbeats carry no size.
  // Ids, hosts and errors are network input: printed escaped and cut (printable.h).
  const std::string who = "worker " + printable(s.worker_id(), 100) + " on " + printable(s.host(), 100);
  if (v.seen == 0)
    log_(who + " joined (session " + std::to_string(s.worker_session()) + ", " +
         (s.envs() > 0 ? size : std::string("waiting for the spec")) + ")");
  else if (s.envs() > 0 && v.last.envs() == 0)
    log_(who + " runs " + size);
  if (v.dead) log_(who + " is back after " + seconds(now - v.seen) + " s");
  if (!s.last_error().empty() && s.last_error() != v.last.last_error())
    log_("worker " + printable(s.worker_id(), 100) + " reports: " + printable(s.last_error(), 500));
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
  const std::string text = printable(e, 500);
  const std::string id = printable(s.worker_id(), 100);
  if (rejected_.size() >= kMaxRejectionsNoted || !rejected_.insert(id + "#" + text).second) return;
  log_("worker " + id + " on " + printable(s.host(), 100) + " cannot join: " + text +
       (rejected_.size() == kMaxRejectionsNoted ? " (no more such lines)" : ""));
}

void WorkerRoster::check(double now) {
  for (auto& [k, v] : views_) {
    if (v.dead || v.last.state() == "finished" || now - v.seen < timeout_) continue;
    v.dead = true;
    log_("worker " + printable(v.last.worker_id(), 100) + " on " + printable(v.last.host(), 100) + " silent for " +
         seconds(now - v.seen) + " s: marked dead; going on with " + std::to_string(live_count(now)) + " workers");
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
