#include "worker_roster.h"

#include <cstdio>

#include "config.h"
#include "printable.h"

namespace farm {

namespace {
std::string seconds(double s) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.1f", s);
  return buf;
}
}  // namespace

bool WorkerRoster::heard(const farm::msg::WorkerStatus& in, double now, const std::string& writer) {
  if (!experiment_id_.empty() && in.experiment_id().empty() && !in.last_error().empty()) {
    note_rejection(in);
    return false;
  }
  if (!experiment_id_.empty() && in.experiment_id() != experiment_id_) {
    // A worker with no experiment yet (it waits for a spec) is not ours until it says so; one of
    // another experiment is noted once per experiment, so a shared domain shows in the log.
    if (!in.experiment_id().empty() && foreign_.size() < kMaxForeignNoted && foreign_.insert(in.experiment_id()).second)
      log_("heartbeats of another experiment, '" + printable(in.experiment_id()) + "' (worker " +
           printable(in.worker_id()) + "), are ignored: only workers of '" + experiment_id_ + "' count");
    return false;
  }
  // A size no worker runs (its --envs is at most kMaxEnvsPerWorker) is not believed: PPO's quota
  // of batches per worker is made from the sizes heard.
  if (in.worker_id().size() > kMaxIdBytes || in.envs() > uint32_t(kMaxEnvsPerWorker) ||
      in.threads() > uint32_t(kMaxEnvsPerWorker)) {
    ++refused_;
    return false;
  }
  const std::string key = in.worker_id() + "#" + std::to_string(in.worker_session());
  auto it = views_.find(key);
  if (it != views_.end() && !it->second.writer.empty() && !writer.empty() && it->second.writer != writer) {
    // Another participant under this worker's id and session (both readable off the bus): not it.
    ++refused_;
    return false;
  }
  if (it == views_.end()) {
    if (!make_room(in.worker_id(), now)) {
      ++refused_;
      return false;
    }
    it = views_.emplace(key, View{}).first;
    it->second.writer = writer;
    it->second.first_seen = now;
  }
  View& v = it->second;
  // Texts are network input: kept cut, and printed escaped and cut (printable.h).
  farm::msg::WorkerStatus s = in;
  cut(s);
  const std::string size = std::to_string(s.envs()) + " envs on " + std::to_string(s.threads()) + " threads";
  // A worker builds its environments once it has the spec: until then its heartbeats carry no size.
  const std::string who = "worker " + printable(s.worker_id(), 100) + " on " + printable(s.host(), 100);
  if (v.seen == 0)
    note(who + " joined (session " + std::to_string(s.worker_session()) + ", " +
             (s.envs() > 0 ? size : std::string("waiting for the spec")) + ")",
         now);
  else if (s.envs() > 0 && v.last.envs() == 0)
    note(who + " runs " + size, now);
  if (v.dead) note(who + " is back after " + seconds(now - v.seen) + " s", now);
  if (!s.last_error().empty() && s.last_error() != v.last.last_error())
    note("worker " + printable(s.worker_id(), 100) + " reports: " + printable(s.last_error(), 500), now);
  const bool joined = v.seen == 0, back = v.dead, sized = !joined && s.envs() > 0 && v.last.envs() == 0;
  v.last = std::move(s);
  v.seen = now;
  v.dead = false;
  if (joined || back) note("", now, joined ? "joined" : "back", &v);
  if (sized) note("", now, "sized", &v);
  return true;
}

void WorkerRoster::cut(farm::msg::WorkerStatus& s) {
  if (s.host().size() > kMaxHostBytes) s.host(s.host().substr(0, kMaxHostBytes));
  if (s.state().size() > kMaxStateBytes) s.state(s.state().substr(0, kMaxStateBytes));
  if (s.last_error().size() > kMaxErrorBytes) s.last_error(s.last_error().substr(0, kMaxErrorBytes));
  if (s.worker_id().size() > kMaxIdBytes + 1) s.worker_id(s.worker_id().substr(0, kMaxIdBytes + 1));  // still refused
}

bool WorkerRoster::make_room(const std::string& id, double now) {
  // Past the id's bound: a session of it not live (the least recently heard), else the one that
  // joined last, so that invented sessions replace each other and not a worker long in the roster.
  const std::string prefix = id + "#";
  const auto before = [&](const View& a, const View& b) {
    const bool la = live(a, now), lb = live(b, now);
    if (la != lb) return !la;
    return la ? a.first_seen > b.first_seen : a.seen < b.seen;
  };
  auto oldest = views_.end();
  size_t same = 0;
  for (auto j = views_.lower_bound(prefix); j != views_.end() && j->first.compare(0, prefix.size(), prefix) == 0;
       ++j, ++same)
    if (oldest == views_.end() || before(j->second, oldest->second)) oldest = j;
  if (same >= kMaxSessionsPerWorker) {
    views_.erase(oldest);
    return true;
  }
  if (views_.size() < kMaxViews) return true;
  // Past the total: the least recently heard of those not live; a live worker is never pushed out.
  auto victim = views_.end();
  for (auto j = views_.begin(); j != views_.end(); ++j)
    if (!live(j->second, now) && (victim == views_.end() || j->second.seen < victim->second.seen)) victim = j;
  if (victim == views_.end()) return false;
  views_.erase(victim);
  return true;
}

void WorkerRoster::note(const std::string& line, double now, const char* change, const View* v) {
  if (now - window_start_ >= kLogWindowS) {
    window_start_ = now;
    window_lines_ = 0;
  }
  // An event alone (empty line) rides on the window of the line it goes with.
  if (window_lines_ >= kLogBurst) {
    held_back_ += !line.empty();
    return;
  }
  window_lines_ += !line.empty();
  if (held_back_ > 0 && !line.empty()) {
    log_(std::to_string(held_back_) + " roster line(s) held back (at most " + std::to_string(kLogBurst) + " per " +
         seconds(kLogWindowS) + " s)");
    held_back_ = 0;
  }
  if (!line.empty()) log_(line);
  if (change && v && event_)
    event_({{"change", change},
            {"worker_id", printable(v->last.worker_id(), 100)},
            {"session", v->last.worker_session()},
            {"host", printable(v->last.host(), 100)},
            {"envs", v->last.envs()},
            {"threads", v->last.threads()}});
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
  int live_now = live_count(now);
  for (auto it = views_.begin(); it != views_.end();) {
    View& v = it->second;
    if (v.dead && now - v.seen >= forget_) {
      it = views_.erase(it);
      continue;
    }
    if (!v.dead && v.last.state() != "finished" && now - v.seen >= timeout_) {
      v.dead = true;
      note("worker " + printable(v.last.worker_id(), 100) + " on " + printable(v.last.host(), 100) + " silent for " +
               seconds(now - v.seen) + " s: marked dead; going on with " + std::to_string(live_now) + " workers",
           now, "dead", &v);
    }
    ++it;
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
