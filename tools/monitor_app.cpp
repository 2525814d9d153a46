// The farm-monitor service (monitor_app.h): what it takes off the bus, and the snapshot of it
// that the table, the JSON log line and the /metrics page are written from.
#include "monitor_app.h"

#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <stdexcept>

#include "meter.h"
#include "printable.h"

namespace farm {

MonitorApp::MonitorApp(const MonitorOptions& o, const std::atomic<bool>& stop)
    : opt_(o),
      stop_(stop),
      metrics_(o.prometheus.empty() ? nullptr : std::make_unique<MetricsServer>(o.prometheus)),
      bus_(o.bus, "farm-monitor " + farm::dds::hostname() + "-" + std::to_string(getpid())),
      // Samples over the bound (anyone on the domain can write them) are refused before memory.
      status_in_(bus_, farm::dds::kWorkerStatusTopic, "status_reader", farm::dds::kMaxStatusBytes),
      stats_in_(bus_, farm::dds::kLearnerStatsTopic, "status_reader", farm::dds::kMaxStatusBytes),
      t0_(farm::now_seconds()) {
  if (!opt_.log_file.empty()) {
    log_.open(opt_.log_file, std::ios::app);
    if (!log_) throw std::runtime_error("cannot append to --log file " + opt_.log_file);
  }
}

int MonitorApp::run() {
  if (opt_.once) return run_once();
  if (metrics_) std::fprintf(stderr, "farm-monitor: Prometheus metrics at %s\n", metrics_->url().c_str());
  double next = farm::now_seconds();
  while (!stop_) {
    drain();
    const double now = farm::now_seconds();
    if (now >= next) {
      show(now);
      next += opt_.interval;
      if (next < now) next = now + opt_.interval;
    }
    status_in_.wait(std::min(0.2, std::max(0.01, next - farm::now_seconds())));
  }
  return 0;
}

int MonitorApp::run_once() {
  const double deadline = t0_ + opt_.wait;
  double first = -1;
  while (!stop_ && farm::now_seconds() < deadline) {
    drain();
    if (first < 0 && (!workers_.empty() || !learners_.empty())) first = farm::now_seconds();
    // One heartbeat round (every worker beats once a second), a heartbeat from every status writer
    // discovered so far (participants are matched one by one, not all at once), and statistics from
    // every learner discovered (they come every log_every_seconds, less often than heartbeats).
    // And at least as many workers as the learners say are live: on a loaded host the learner's
    // statistics can arrive before the workers' status writers are matched at all.
    size_t reported = 0;
    for (const auto& [experiment, v] : learners_) reported += v.last.workers();
    if (first >= 0 && farm::now_seconds() - first >= 1.5 && int(heard_.size()) >= status_in_.matched() &&
        int(stats_heard_.size()) >= stats_in_.matched() && workers_.size() >= reported)
      break;
    status_in_.wait(0.1);
  }
  drain();
  const double now = farm::now_seconds();
  if (workers_.empty() && learners_.empty()) {
    std::fprintf(stderr,
                 "farm-monitor: nothing found on DDS domain %d within %.1f s: no WorkerStatus or LearnerStats%s "
                 "(check --domain, --dds-profiles %s and, with a discovery server, ROS_DISCOVERY_SERVER)\n",
                 bus_.domain(), opt_.wait,
                 opt_.experiment.empty() ? "" : (" of experiment '" + opt_.experiment + "'").c_str(),
                 bus_.profiles_file().c_str());
    write_log(snapshot(now));
    return 1;
  }
  const MonitorSnapshot snap = snapshot(now);
  std::fputs(render_table(snap).c_str(), stdout);
  std::fflush(stdout);
  write_log(snap);
  return 0;
}

bool MonitorApp::wanted(const std::string& experiment) const {
  return opt_.experiment.empty() || experiment == opt_.experiment;
}

void MonitorApp::drain() {
  const double now = farm::now_seconds();
  farm::msg::WorkerStatus s;
  eprosima::fastdds::dds::SampleInfo info;
  while (status_in_.take(s, info)) {
    // Under DDS Security a heartbeat says only what its writer's certificate may: the worker id must
    // be the certificate's name, as the learner's roster asks. A leaked certificate cannot show
    // another worker in error or invent workers in the table and the series.
    if (!bus_.security_dir().empty() && bus_.authenticated_name(info.sample_identity.writer_guid()) != s.worker_id()) {
      if (++refused_for_name_ <= kMaxRefusalNotes)
        std::fprintf(stderr,
                     "farm-monitor: ignored a heartbeat of worker '%s' from a participant whose certificate "
                     "name is '%s'%s\n",
                     printable(s.worker_id(), 100).c_str(),
                     printable(bus_.authenticated_name(info.sample_identity.writer_guid()), 100).c_str(),
                     refused_for_name_ == kMaxRefusalNotes ? " (no more such lines)" : "");
      continue;
    }
    // Heartbeats are network input, and anyone on the domain can invent them: texts are kept cut
    // and every table bounded (the least recently heard worker or learner makes room).
    if (s.worker_id().size() > kMaxTextBytes) s.worker_id(s.worker_id().substr(0, kMaxTextBytes));
    if (s.host().size() > kMaxTextBytes) s.host(s.host().substr(0, kMaxTextBytes));
    if (s.experiment_id().size() > kMaxTextBytes) s.experiment_id(s.experiment_id().substr(0, kMaxTextBytes));
    if (s.state().size() > kMaxTextBytes) s.state(s.state().substr(0, kMaxTextBytes));
    if (s.last_error().size() > 4 * kMaxTextBytes) s.last_error(s.last_error().substr(0, 4 * kMaxTextBytes));
    if (heard_.size() < kMaxEntries) heard_.insert(key(s));
    if (!wanted(s.experiment_id())) continue;
    if (workers_.size() >= kMaxEntries && !workers_.count(key(s))) {
      auto oldest = workers_.begin();
      for (auto it = workers_.begin(); it != workers_.end(); ++it)
        if (it->second.seen < oldest->second.seen) oldest = it;
      workers_.erase(oldest);
    }
    // A restarted worker (same id, new session) replaces its earlier session.
    for (auto it = workers_.begin(); it != workers_.end();) {
      if (it->second.last.worker_id() == s.worker_id() && it->second.last.worker_session() != s.worker_session())
        it = workers_.erase(it);
      else
        ++it;
    }
    WorkerView& v = workers_[key(s)];
    if (v.first_seen == 0) v.first_seen = now;
    v.last = s;
    v.seen = now;
    v.history.emplace_back(now, s.env_steps());
    while (v.history.size() > 2 && now - v.history.front().first > 5.0) v.history.pop_front();
  }
  farm::msg::LearnerStats l;
  while (stats_in_.take(l)) {
    if (l.experiment_id().size() > kMaxTextBytes) l.experiment_id(l.experiment_id().substr(0, kMaxTextBytes));
    if (stats_heard_.size() < kMaxEntries) stats_heard_.insert(l.experiment_id());
    if (!wanted(l.experiment_id())) continue;
    if (learners_.size() >= kMaxEntries && !learners_.count(l.experiment_id())) {
      auto oldest = learners_.begin();
      for (auto it = learners_.begin(); it != learners_.end(); ++it)
        if (it->second.seen < oldest->second.seen) oldest = it;
      learners_.erase(oldest);
    }
    LearnerView& v = learners_[l.experiment_id()];
    v.last = l;
    v.seen = now;
    latest_learner_ = l.experiment_id();
  }
  for (auto it = workers_.begin(); it != workers_.end();) {
    if (now - it->second.seen > opt_.timeout + opt_.forget)
      it = workers_.erase(it);
    else
      ++it;
  }
}

std::string MonitorApp::key(const farm::msg::WorkerStatus& s) {
  return s.worker_id() + "#" + std::to_string(s.worker_session());
}

bool MonitorApp::dead(const WorkerView& v, double now) const { return now - v.seen > opt_.timeout; }

// What the table and the log call the worker's state: its own, or dead when silent.
std::string MonitorApp::state(const WorkerView& v, double now) const { return dead(v, now) ? "dead" : v.last.state(); }

// Counts toward the totals: alive and not finished.
bool MonitorApp::live(const WorkerView& v, double now) const { return !dead(v, now) && v.last.state() != "finished"; }

double MonitorApp::rate(const WorkerView& v, double now) const {
  if (dead(v, now)) return 0.0;
  if (v.history.size() >= 2) {
    const auto& a = v.history.front();
    const auto& b = v.history.back();
    if (b.first - a.first >= 0.5 && b.second >= a.second) return double(b.second - a.second) / (b.first - a.first);
  }
  return v.last.steps_per_second();
}

MonitorSnapshot MonitorApp::snapshot(double now) const {
  MonitorSnapshot s;
  timespec ts;
  clock_gettime(CLOCK_REALTIME, &ts);
  s.unix_ms = int64_t(ts.tv_sec) * 1000 + ts.tv_nsec / 1000000;
  s.elapsed_s = now - t0_;
  s.domain = bus_.domain();
  s.experiment = opt_.experiment;
  s.timeout = opt_.timeout;
  for (auto& [k, v] : workers_) {
    const auto& m = v.last;
    WorkerRow w;
    w.id = m.worker_id();
    w.host = m.host();
    w.experiment = m.experiment_id();
    w.last_error = m.last_error();
    w.session = m.worker_session();
    w.envs = m.envs();
    w.threads = m.threads();
    w.steps_per_second = rate(v, now);
    w.env_steps = m.env_steps();
    w.batches_sent = m.batches_sent();
    w.policy_version = m.policy_version();
    w.state = state(v, now);
    w.alive = !dead(v, now);
    w.age_s = now - v.seen;
    WorkerTotals& t = s.totals;
    if (!w.alive)
      ++t.dead;
    else if (!live(v, now))
      ++t.finished;
    else {
      ++t.live;
      t.envs += w.envs;
      t.env_steps += w.env_steps;
      t.batches += w.batches_sent;
      t.steps_per_second += w.steps_per_second;
    }
    s.workers.push_back(std::move(w));
  }
  std::stable_sort(s.workers.begin(), s.workers.end(), [](const WorkerRow& a, const WorkerRow& b) {
    if (a.host != b.host) return a.host < b.host;
    return a.id < b.id;
  });
  for (auto& [experiment, v] : learners_) {  // a map: sorted by experiment id
    const auto& m = v.last;
    if (experiment == latest_learner_) s.latest_learner = int(s.learners.size());
    LearnerRow l;
    l.experiment = m.experiment_id();
    l.age_s = now - v.seen;
#define FARM_COPY(name, member, type) l.member = m.member();
    FARM_LEARNER_STATS_FIELDS(FARM_COPY)
#undef FARM_COPY
    for (const auto& st : m.stats()) {
      if (l.stats.size() >= kMaxStats) break;
      l.stats.push_back({st.name().substr(0, kMaxTextBytes), st.unit().substr(0, kMaxTextBytes), st.value()});
    }
    s.learners.push_back(std::move(l));
  }
  return s;
}

void MonitorApp::show(double now) {
  const MonitorSnapshot snap = snapshot(now);
  if (!opt_.quiet) {
    // On a terminal the table refreshes in place (home, clear); into a file, one after the other.
    std::fputs(isatty(STDOUT_FILENO) ? "\033[H\033[2J" : "\n", stdout);
    std::fputs(render_table(snap).c_str(), stdout);
    std::fflush(stdout);
  }
  write_log(snap);
  if (metrics_) {
    prometheus_.update(snap);
    metrics_->publish(prometheus_.page());
  }
}

void MonitorApp::write_log(const MonitorSnapshot& s) {
  if (!log_.is_open()) return;
  log_ << render_json_line(s);
  log_.flush();
}

}  // namespace farm
