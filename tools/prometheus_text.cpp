// farm-monitor's series in a prometheus-cpp registry, and their page (prometheus_text.h).
#include "prometheus_text.h"

#include <prometheus/metric_family.h>
#include <prometheus/registry.h>
#include <prometheus/text_serializer.h>

#include <cmath>
#include <cstdint>
#include <functional>
#include <set>
#include <utility>

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
  return valid;
}

namespace {

// The series of one family that are not in want (or whose value there is not a finite number: a
// gauge without a value has no sample rather than a NaN) leave the family.
template <typename T>
void drop_absent(prometheus::Family<T>& family, std::map<prometheus::Labels, T*>& series,
                 const std::map<prometheus::Labels, double>& want) {
  for (auto it = series.begin(); it != series.end();) {
    const auto w = want.find(it->first);
    if (w == want.end() || !std::isfinite(w->second)) {
      family.Remove(it->second);
      it = series.erase(it);
    } else {
      ++it;
    }
  }
}

}  // namespace

PrometheusMetrics::PrometheusMetrics(const PrometheusLimits& limits)
    : limits_(limits), registry_(std::make_shared<prometheus::Registry>()) {}

PrometheusMetrics::Tracked<prometheus::Gauge>& PrometheusMetrics::gauge(const std::string& name,
                                                                        const std::string& help) {
  auto [it, added] = gauges_.try_emplace(name);
  if (added) {
    it->second.family = &prometheus::BuildGauge().Name(name).Help(help).Register(*registry_);
    order_.push_back({name, help, prometheus::MetricType::Gauge});
  }
  return it->second;
}

PrometheusMetrics::Tracked<prometheus::Counter>& PrometheusMetrics::counter(const std::string& name,
                                                                            const std::string& help) {
  auto [it, added] = counters_.try_emplace(name);
  if (added) {
    it->second.family = &prometheus::BuildCounter().Name(name).Help(help).Register(*registry_);
    order_.push_back({name, help, prometheus::MetricType::Counter});
  }
  return it->second;
}

void PrometheusMetrics::sync(Tracked<prometheus::Gauge>& t, const Values& want) {
  drop_absent(*t.family, t.series, want);
  for (const auto& [labels, v] : want) {
    if (!std::isfinite(v)) continue;
    prometheus::Gauge*& g = t.series[labels];
    if (!g) g = &t.family->Add(labels);
    g->Set(v);
  }
}

void PrometheusMetrics::sync(Tracked<prometheus::Counter>& t, const Values& want) {
  drop_absent(*t.family, t.series, want);
  for (const auto& [labels, v] : want) {
    if (!std::isfinite(v)) continue;
    prometheus::Counter*& c = t.series[labels];
    if (c && v < c->Value()) {  // the source started over (a resumed learner): so does the counter
      t.family->Remove(c);
      c = nullptr;
    }
    if (!c) c = &t.family->Add(labels);
    c->Increment(v - c->Value());
  }
}

void PrometheusMetrics::update(const MonitorSnapshot& s) {
  const auto label = [&](const std::string& v) { return prometheus_label_value(v, limits_.max_label_bytes); };

  // The workers and learners exported, each with its label set, distinct after bounding.
  std::vector<std::pair<const WorkerRow*, prometheus::Labels>> workers;
  std::set<prometheus::Labels> seen;
  uint64_t not_exported = 0;
  for (const WorkerRow& w : s.workers) {
    prometheus::Labels l{{"worker", label(w.id)}, {"host", label(w.host)}, {"experiment", label(w.experiment)}};
    if (workers.size() >= limits_.max_workers || !seen.insert(l).second)
      ++not_exported;
    else
      workers.emplace_back(&w, std::move(l));
  }
  std::vector<std::pair<const LearnerRow*, prometheus::Labels>> learners;
  seen.clear();
  for (const LearnerRow& r : s.learners) {
    prometheus::Labels l{{"experiment", label(r.experiment)}};
    if (learners.size() < limits_.max_learners && seen.insert(l).second) learners.emplace_back(&r, std::move(l));
  }

  const auto one = [](double v) { return Values{{prometheus::Labels{}, v}}; };
  const auto set_gauge = [&](const char* name, const char* help, const Values& v) { sync(gauge(name, help), v); };
  const auto set_counter = [&](const char* name, const char* help, const Values& v) { sync(counter(name, help), v); };
  const auto per_worker = [&](const std::function<double(const WorkerRow&)>& value) {
    Values v;
    for (const auto& [w, l] : workers) v[l] = value(*w);
    return v;
  };
  const auto per_learner = [&](const std::function<double(const LearnerRow&)>& value) {
    Values v;
    for (const auto& [r, l] : learners) v[l] = value(*r);
    return v;
  };

  // To the millisecond, as the --log line's unix_time.
  set_gauge("farm_monitor_snapshot_timestamp_seconds",
            "Unix time at which farm-monitor took the snapshot these values come from.", one(s.unix_ms / 1000.0));
  set_gauge("farm_monitor_worker_timeout_seconds",
            "A worker silent this long is shown dead and left out of the totals (--timeout).", one(s.timeout));
  set_gauge("farm_monitor_workers_not_exported",
            "Workers in the monitor's table without series here: past the export bound, or with labels that, "
            "bounded, repeat another worker's.",
            one(double(not_exported)));

  // Per worker, from its latest heartbeat (WorkerStatus).
  set_gauge("farm_worker_up", "1 while the worker's heartbeats arrive, 0 once it is silent past the timeout.",
            per_worker([](const WorkerRow& w) { return w.alive ? 1.0 : 0.0; }));
  Values states;
  for (const auto& [w, l] : workers) {
    const auto& known = prometheus_worker_states();
    bool is_known = false;
    for (const std::string& st : known) is_known = is_known || st == w->state;
    for (const std::string& st : known) {
      prometheus::Labels with_state = l;
      with_state["state"] = st;
      states[with_state] = (is_known ? st == w->state : st == "other") ? 1 : 0;
    }
  }
  set_gauge("farm_worker_state",
            "1 for the worker's current state (dead: silent past the timeout; other: a state this monitor does not "
            "know), 0 for the others.",
            states);
  set_gauge("farm_worker_envs", "Environments the worker simulates.",
            per_worker([](const WorkerRow& w) { return double(w.envs); }));
  set_gauge("farm_worker_threads", "Threads stepping the worker's environments.",
            per_worker([](const WorkerRow& w) { return double(w.threads); }));
  set_gauge("farm_worker_env_steps_per_second",
            "Environment steps per second over the worker's recent heartbeats (0 when dead).",
            per_worker([](const WorkerRow& w) { return w.steps_per_second; }));
  set_counter("farm_worker_env_steps_total", "Environment steps the worker has simulated in this session.",
              per_worker([](const WorkerRow& w) { return double(w.env_steps); }));
  set_counter("farm_worker_batches_sent_total", "Transition batches the worker has sent in this session.",
              per_worker([](const WorkerRow& w) { return double(w.batches_sent); }));
  set_gauge("farm_worker_policy_version", "Version of the policy weights the worker acts with.",
            per_worker([](const WorkerRow& w) { return double(w.policy_version); }));
  set_gauge("farm_worker_last_heartbeat_age_seconds", "Seconds since the worker's last heartbeat arrived.",
            per_worker([](const WorkerRow& w) { return w.age_s; }));

  // Totals over the live workers (alive, not finished): the table's TOTAL line. They fall when a
  // worker dies or finishes, so every one is a gauge.
  const WorkerTotals& t = s.totals;
  set_gauge("farm_workers", "Workers in the monitor's table by status: live, dead (silent) or finished.",
            Values{{{{"status", "live"}}, double(t.live)},
                   {{{"status", "dead"}}, double(t.dead)},
                   {{{"status", "finished"}}, double(t.finished)}});
  set_gauge("farm_total_envs", "Environments of the live workers.", one(double(t.envs)));
  set_gauge("farm_total_env_steps_per_second", "Environment steps per second of the live workers together.",
            one(t.steps_per_second));
  set_gauge("farm_total_env_steps",
            "Environment steps of the live workers' current sessions (falls when a worker leaves).",
            one(double(t.env_steps)));
  set_gauge("farm_total_batches_sent",
            "Batches sent by the live workers' current sessions (falls when a worker leaves).", one(double(t.batches)));

  // Per learner, from its latest LearnerStats.
  set_gauge("farm_learner_last_stats_age_seconds", "Seconds since the learner's last statistics arrived.",
            per_learner([](const LearnerRow& r) { return r.age_s; }));
  set_gauge("farm_learner_elapsed_seconds", "Seconds the run has trained (resumed runs included).",
            per_learner([](const LearnerRow& r) { return r.elapsed_seconds; }));
  set_counter("farm_learner_env_steps_total", "Environment steps the learner has ingested.",
              per_learner([](const LearnerRow& r) { return double(r.env_steps); }));
  set_gauge("farm_learner_env_steps_per_second", "Environment steps per second the learner ingests.",
            per_learner([](const LearnerRow& r) { return r.env_steps_per_second; }));
  set_counter("farm_learner_updates_total", "Gradient updates the learner has made.",
              per_learner([](const LearnerRow& r) { return double(r.updates); }));
  set_gauge("farm_learner_updates_per_second", "Gradient updates per second.",
            per_learner([](const LearnerRow& r) { return r.updates_per_second; }));
  set_gauge("farm_learner_buffer_fill_ratio", "Fill of the replay buffer or rollout storage, 0 to 1.",
            per_learner([](const LearnerRow& r) { return r.buffer_fill; }));
  set_gauge("farm_learner_policy_lag_versions",
            "Mean policy versions between the learner's policy and the one that made each batch it accepted.",
            per_learner([](const LearnerRow& r) { return r.policy_lag; }));
  set_gauge("farm_learner_critic_loss", "Latest critic (value) loss.",
            per_learner([](const LearnerRow& r) { return r.critic_loss; }));
  set_gauge("farm_learner_actor_loss", "Latest actor (policy) loss.",
            per_learner([](const LearnerRow& r) { return r.actor_loss; }));
  set_gauge("farm_learner_mean_return", "Mean return of the recent training episodes (absent: none yet).",
            per_learner([](const LearnerRow& r) { return r.mean_return; }));
  set_gauge("farm_learner_eval_return", "Mean return of the latest deterministic evaluation (absent: none yet).",
            per_learner([](const LearnerRow& r) { return r.eval_return; }));
  Values batches;
  for (const auto& [r, l] : learners) {
    const std::pair<const char*, uint64_t> results[] = {{"ok", r->batches_ok},
                                                        {"lost", r->batches_lost},
                                                        {"duplicate", r->batches_duplicate},
                                                        {"invalid", r->batches_invalid}};
    for (const auto& [result, n] : results) {
      prometheus::Labels with_result = l;
      with_result["result"] = result;
      batches[with_result] = double(n);
    }
  }
  set_counter("farm_learner_batches_total",
              "Transition batches the learner has accounted, by result: ok (accepted), lost (a gap in a worker's "
              "sequence), duplicate, invalid (refused by validation).",
              batches);
  set_gauge("farm_learner_workers", "Workers the learner counts live.",
            per_learner([](const LearnerRow& r) { return double(r.workers); }));
  // Every field of the learner's statistics record, as it declares it (name and unit): a field the
  // learner adds has a series here without a change to the monitor.
  Values stats;
  for (const auto& [r, l] : learners) {
    for (const LearnerRow::Stat& st : r->stats) {
      prometheus::Labels with_name = l;
      with_name["name"] = label(st.name);
      with_name["unit"] = label(st.unit);
      stats.emplace(std::move(with_name), st.value);  // a name repeated after bounding: its first
    }
  }
  set_gauge("farm_learner_stat",
            "Each field of the learner's statistics record (learner.csv's columns) by name and unit; absent: none "
            "yet.",
            stats);
}

std::string PrometheusMetrics::page() const {
  // The registry leaves out a family without series; the page lists it with its HELP and TYPE.
  std::map<std::string, prometheus::MetricFamily> collected;
  for (prometheus::MetricFamily& f : registry_->Collect()) collected[f.name] = std::move(f);
  std::vector<prometheus::MetricFamily> families;
  for (const Header& h : order_) {
    auto it = collected.find(h.name);
    if (it != collected.end()) {
      families.push_back(std::move(it->second));
    } else {
      prometheus::MetricFamily empty;
      empty.name = h.name;
      empty.help = h.help;
      empty.type = h.type;
      families.push_back(std::move(empty));
    }
  }
  return prometheus::TextSerializer().Serialize(families);
}

std::string render_prometheus(const MonitorSnapshot& s, const PrometheusLimits& limits) {
  PrometheusMetrics m(limits);
  m.update(s);
  return m.page();
}

}  // namespace farm
