// The Prometheus text exposition of a farm-monitor snapshot (prometheus_text.h).
#include "prometheus_text.h"

#include <cinttypes>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <set>
#include <sstream>

namespace farm {

namespace {

const char kReplacement[] = "\xEF\xBF\xBD";  // U+FFFD

// Length of the valid UTF-8 sequence at s[i], or 0 when the bytes there are not one.
size_t utf8_sequence(const std::string& s, size_t i) {
  const auto b = [&](size_t k) { return static_cast<unsigned char>(s[k]); };
  const unsigned char c = b(i);
  if (c < 0x80) return 1;
  size_t n;
  uint32_t cp;
  if (c >= 0xC2 && c <= 0xDF) {
    n = 2;
    cp = c & 0x1F;
  } else if (c >= 0xE0 && c <= 0xEF) {
    n = 3;
    cp = c & 0x0F;
  } else if (c >= 0xF0 && c <= 0xF4) {
    n = 4;
    cp = c & 0x07;
  } else {
    return 0;
  }
  if (i + n > s.size()) return 0;
  for (size_t k = 1; k < n; ++k) {
    if ((b(i + k) & 0xC0) != 0x80) return 0;
    cp = (cp << 6) | (b(i + k) & 0x3F);
  }
  // Overlong forms, UTF-16 surrogates and code points past U+10FFFF are not UTF-8.
  if ((n == 3 && cp < 0x800) || (n == 4 && (cp < 0x10000 || cp > 0x10FFFF)) || (cp >= 0xD800 && cp <= 0xDFFF)) return 0;
  return n;
}

// The shortest decimal that reads back as exactly v (0.817, not 0.81699999999999995).
std::string number(double v) {
  char buf[64];
  for (int digits = 15; digits <= 17; ++digits) {
    std::snprintf(buf, sizeof(buf), "%.*g", digits, v);
    if (std::strtod(buf, nullptr) == v) break;
  }
  return buf;
}

// Writes families one after the other: every sample of a family right after its # HELP and # TYPE.
class Exposition {
 public:
  void family(const char* name, const char* type, const char* help) {
    name_ = name;
    o_ << "# HELP " << name << ' ' << help << "\n# TYPE " << name << ' ' << type << '\n';
  }
  // labels: the inside of {...}, already escaped; a gauge that is not a finite number (no
  // evaluation yet) has no sample rather than a NaN.
  void sample(const std::string& labels, double v) {
    if (std::isfinite(v)) line(labels) << number(v) << '\n';
  }
  void sample(const std::string& labels, uint64_t v) { line(labels) << v << '\n'; }
  void sample_text(const std::string& labels, const std::string& v) { line(labels) << v << '\n'; }
  std::string str() const { return o_.str(); }

 private:
  std::ostringstream& line(const std::string& labels) {
    o_ << name_;
    if (!labels.empty()) o_ << '{' << labels << '}';
    o_ << ' ';
    return o_;
  }
  std::ostringstream o_;
  std::string name_;
};

}  // namespace

const std::vector<std::string>& prometheus_worker_states() {
  static const std::vector<std::string> states = {"starting",
                                                  "waiting_for_learner",
                                                  "waiting_for_weights",
                                                  "running",
                                                  "throttled",
                                                  "backpressure",
                                                  "error",
                                                  "finished",
                                                  "dead",
                                                  "other"};
  return states;
}

std::string prometheus_label_value(const std::string& raw, size_t max_bytes) {
  std::string valid;  // raw as valid UTF-8 without control characters, cut at max_bytes
  for (size_t i = 0; i < raw.size();) {
    size_t n = utf8_sequence(raw, i);
    const unsigned char c = static_cast<unsigned char>(raw[i]);
    const bool control = n == 1 && ((c < 0x20 && c != '\n') || c == 0x7F);
    const std::string piece = (n == 0 || control) ? std::string(kReplacement) : raw.substr(i, n);
    if (valid.size() + piece.size() > max_bytes) break;
    valid += piece;
    i += n ? n : 1;
  }
  std::string out;
  for (char c : valid) {
    if (c == '\\')
      out += "\\\\";
    else if (c == '"')
      out += "\\\"";
    else if (c == '\n')
      out += "\\n";
    else
      out += c;
  }
  return out;
}

std::string render_prometheus(const MonitorSnapshot& s, const PrometheusLimits& limits) {
  const auto label = [&](const std::string& v) { return prometheus_label_value(v, limits.max_label_bytes); };

  // The workers and learners exported, each with its label set, distinct after bounding.
  std::vector<std::pair<const WorkerRow*, std::string>> workers;
  std::set<std::string> seen;
  uint64_t not_exported = 0;
  for (const WorkerRow& w : s.workers) {
    std::string l =
        "worker=\"" + label(w.id) + "\",host=\"" + label(w.host) + "\",experiment=\"" + label(w.experiment) + "\"";
    if (workers.size() >= limits.max_workers || !seen.insert(l).second)
      ++not_exported;
    else
      workers.emplace_back(&w, l);
  }
  std::vector<std::pair<const LearnerRow*, std::string>> learners;
  seen.clear();
  for (const LearnerRow& r : s.learners) {
    std::string l = "experiment=\"" + label(r.experiment) + "\"";
    if (learners.size() < limits.max_learners && seen.insert(l).second) learners.emplace_back(&r, l);
  }

  Exposition e;
  const auto per_worker = [&](const char* name, const char* type, const char* help,
                              const std::function<void(const WorkerRow&, const std::string&)>& add) {
    e.family(name, type, help);
    for (auto& [w, l] : workers) add(*w, l);
  };
  const auto per_learner = [&](const char* name, const char* type, const char* help,
                               const std::function<void(const LearnerRow&, const std::string&)>& add) {
    e.family(name, type, help);
    for (auto& [r, l] : learners) add(*r, l);
  };

  e.family("farm_monitor_snapshot_timestamp_seconds", "gauge",
           "Unix time at which farm-monitor took the snapshot these values come from.");
  char stamp[48];  // to the millisecond, as the --log line's unix_time
  std::snprintf(stamp, sizeof(stamp), "%lld.%03d", static_cast<long long>(s.unix_ms / 1000), int(s.unix_ms % 1000));
  e.sample_text("", stamp);
  e.family("farm_monitor_worker_timeout_seconds", "gauge",
           "A worker silent this long is shown dead and left out of the totals (--timeout).");
  e.sample("", s.timeout);
  e.family("farm_monitor_workers_not_exported", "gauge",
           "Workers in the monitor's table without series here: past the export bound, or with labels that, "
           "bounded, repeat another worker's.");
  e.sample("", not_exported);

  // Per worker, from its latest heartbeat (WorkerStatus).
  per_worker("farm_worker_up", "gauge", "1 while the worker's heartbeats arrive, 0 once it is silent past the timeout.",
             [&](const WorkerRow& w, const std::string& l) { e.sample(l, uint64_t(w.alive ? 1 : 0)); });
  e.family("farm_worker_state", "gauge",
           "1 for the worker's current state (dead: silent past the timeout; other: a state this monitor does not "
           "know), 0 for the others.");
  for (auto& [w, l] : workers) {
    const auto& states = prometheus_worker_states();
    bool known = false;
    for (const std::string& st : states) known = known || st == w->state;
    for (const std::string& st : states) {
      const bool on = known ? st == w->state : st == "other";
      e.sample(l + ",state=\"" + st + "\"", uint64_t(on ? 1 : 0));
    }
  }
  per_worker("farm_worker_envs", "gauge", "Environments the worker simulates.",
             [&](const WorkerRow& w, const std::string& l) { e.sample(l, uint64_t(w.envs)); });
  per_worker("farm_worker_threads", "gauge", "Threads stepping the worker's environments.",
             [&](const WorkerRow& w, const std::string& l) { e.sample(l, uint64_t(w.threads)); });
  per_worker("farm_worker_env_steps_per_second", "gauge",
             "Environment steps per second over the worker's recent heartbeats (0 when dead).",
             [&](const WorkerRow& w, const std::string& l) { e.sample(l, w.steps_per_second); });
  per_worker("farm_worker_env_steps_total", "counter", "Environment steps the worker has simulated in this session.",
             [&](const WorkerRow& w, const std::string& l) { e.sample(l, w.env_steps); });
  per_worker("farm_worker_batches_sent_total", "counter", "Transition batches the worker has sent in this session.",
             [&](const WorkerRow& w, const std::string& l) { e.sample(l, w.batches_sent); });
  per_worker("farm_worker_policy_version", "gauge", "Version of the policy weights the worker acts with.",
             [&](const WorkerRow& w, const std::string& l) { e.sample(l, w.policy_version); });
  per_worker("farm_worker_last_heartbeat_age_seconds", "gauge", "Seconds since the worker's last heartbeat arrived.",
             [&](const WorkerRow& w, const std::string& l) { e.sample(l, w.age_s); });

  // Totals over the live workers (alive, not finished): the table's TOTAL line. They fall when a
  // worker dies or finishes, so every one is a gauge.
  const WorkerTotals& t = s.totals;
  e.family("farm_workers", "gauge", "Workers in the monitor's table by status: live, dead (silent) or finished.");
  e.sample("status=\"live\"", uint64_t(t.live));
  e.sample("status=\"dead\"", uint64_t(t.dead));
  e.sample("status=\"finished\"", uint64_t(t.finished));
  e.family("farm_total_envs", "gauge", "Environments of the live workers.");
  e.sample("", t.envs);
  e.family("farm_total_env_steps_per_second", "gauge", "Environment steps per second of the live workers together.");
  e.sample("", t.steps_per_second);
  e.family("farm_total_env_steps", "gauge",
           "Environment steps of the live workers' current sessions (falls when a worker leaves).");
  e.sample("", t.env_steps);
  e.family("farm_total_batches_sent", "gauge",
           "Batches sent by the live workers' current sessions (falls when a worker leaves).");
  e.sample("", t.batches);

  // Per learner, from its latest LearnerStats.
  per_learner("farm_learner_last_stats_age_seconds", "gauge", "Seconds since the learner's last statistics arrived.",
              [&](const LearnerRow& r, const std::string& l) { e.sample(l, r.age_s); });
  per_learner("farm_learner_elapsed_seconds", "gauge", "Seconds the run has trained (resumed runs included).",
              [&](const LearnerRow& r, const std::string& l) { e.sample(l, r.elapsed_s); });
  per_learner("farm_learner_env_steps_total", "counter", "Environment steps the learner has ingested.",
              [&](const LearnerRow& r, const std::string& l) { e.sample(l, r.env_steps); });
  per_learner("farm_learner_env_steps_per_second", "gauge", "Environment steps per second the learner ingests.",
              [&](const LearnerRow& r, const std::string& l) { e.sample(l, r.env_steps_per_second); });
  per_learner("farm_learner_updates_total", "counter", "Gradient updates the learner has made.",
              [&](const LearnerRow& r, const std::string& l) { e.sample(l, r.updates); });
  per_learner("farm_learner_updates_per_second", "gauge", "Gradient updates per second.",
              [&](const LearnerRow& r, const std::string& l) { e.sample(l, r.updates_per_second); });
  per_learner("farm_learner_buffer_fill_ratio", "gauge", "Fill of the replay buffer or rollout storage, 0 to 1.",
              [&](const LearnerRow& r, const std::string& l) { e.sample(l, r.buffer_fill); });
  per_learner("farm_learner_policy_lag_versions", "gauge",
              "Mean policy versions between the learner's policy and the one that made each batch it accepted.",
              [&](const LearnerRow& r, const std::string& l) { e.sample(l, r.policy_lag); });
  per_learner("farm_learner_critic_loss", "gauge", "Latest critic (value) loss.",
              [&](const LearnerRow& r, const std::string& l) { e.sample(l, r.critic_loss); });
  per_learner("farm_learner_actor_loss", "gauge", "Latest actor (policy) loss.",
              [&](const LearnerRow& r, const std::string& l) { e.sample(l, r.actor_loss); });
  per_learner("farm_learner_mean_return", "gauge", "Mean return of the recent training episodes (absent: none yet).",
              [&](const LearnerRow& r, const std::string& l) { e.sample(l, r.mean_return); });
  per_learner("farm_learner_eval_return", "gauge",
              "Mean return of the latest deterministic evaluation (absent: none yet).",
              [&](const LearnerRow& r, const std::string& l) { e.sample(l, r.eval_return); });
  e.family("farm_learner_batches_total", "counter",
           "Transition batches the learner has accounted, by result: ok (accepted), lost (a gap in a worker's "
           "sequence), duplicate, invalid (refused by validation).");
  for (auto& [r, l] : learners) {
    e.sample(l + ",result=\"ok\"", r->batches_ok);
    e.sample(l + ",result=\"lost\"", r->batches_lost);
    e.sample(l + ",result=\"duplicate\"", r->batches_duplicate);
    e.sample(l + ",result=\"invalid\"", r->batches_invalid);
  }
  per_learner("farm_learner_workers", "gauge", "Workers the learner counts live.",
              [&](const LearnerRow& r, const std::string& l) { e.sample(l, uint64_t(r.workers)); });
  return e.str();
}

}  // namespace farm
