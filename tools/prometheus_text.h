// The farm-monitor snapshot (monitor_snapshot.h) as Prometheus metrics: a prometheus-cpp Registry
// of gauge and counter families, brought to each snapshot, and its page in the text exposition
// format 0.0.4 (prometheus-cpp's TextSerializer): the series farm-monitor --prometheus serves at
// /metrics. Names, types and labels are listed in docs/guides/monitoring.md; deploy/grafana/farm.json
// queries them.
//
// Worker ids, hosts and experiment ids come off the bus, where any participant of the domain can
// write them, so label values are bounded (truncated on a UTF-8 boundary) and made valid UTF-8
// before they reach the registry (the serializer escapes backslash, double quote and line feed);
// workers past a bound, or whose bounded labels would repeat another's (which would make
// Prometheus refuse the whole scrape), are left out and counted in farm_monitor_workers_not_exported.
#pragma once

#include <prometheus/counter.h>
#include <prometheus/family.h>
#include <prometheus/gauge.h>
#include <prometheus/labels.h>
#include <prometheus/metric_type.h>
#include <prometheus/registry.h>

#include <cstddef>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "monitor_snapshot.h"

namespace farm {

struct PrometheusLimits {
  size_t max_label_bytes = 128;  // longest label value, in bytes of UTF-8
  size_t max_workers = 4096;     // workers exported at most (the table's order: host, then id)
  size_t max_learners = 64;      // learners (experiments) exported at most
};

// The worker states farm_worker_state has a series for; any other state string is "other".
const std::vector<std::string>& prometheus_worker_states();

// A label value as given to the registry: at most max_bytes of valid UTF-8, each invalid byte and
// each control character other than a line feed replaced by U+FFFD.
std::string prometheus_label_value(const std::string& raw, size_t max_bytes);

// The registry of farm-monitor's series. update() adds the series of workers and learners that
// appear, sets every value and removes the series of those that left the snapshot (and of gauges
// without a finite value, e.g. no evaluation yet), so a scrape shows the snapshot's farm only.
class PrometheusMetrics {
 public:
  explicit PrometheusMetrics(const PrometheusLimits& limits = {});

  void update(const MonitorSnapshot& s);

  // Every family with its # HELP and # TYPE lines, also those without a series now (the dashboard
  // and Prometheus see the same names from the first scrape on).
  std::string page() const;

  const std::shared_ptr<prometheus::Registry>& registry() const { return registry_; }

 private:
  // One family and its series now: what update() compares the snapshot's series with.
  template <typename T>
  struct Tracked {
    prometheus::Family<T>* family = nullptr;
    std::map<prometheus::Labels, T*> series;
  };
  using Values = std::map<prometheus::Labels, double>;
  struct Header {
    std::string name, help;
    prometheus::MetricType type;
  };

  Tracked<prometheus::Gauge>& gauge(const std::string& name, const std::string& help);
  Tracked<prometheus::Counter>& counter(const std::string& name, const std::string& help);
  static void sync(Tracked<prometheus::Gauge>& t, const Values& want);
  static void sync(Tracked<prometheus::Counter>& t, const Values& want);

  PrometheusLimits limits_;
  std::shared_ptr<prometheus::Registry> registry_;
  std::map<std::string, Tracked<prometheus::Gauge>> gauges_;
  std::map<std::string, Tracked<prometheus::Counter>> counters_;
  std::vector<Header> order_;  // families in the order the page lists them
};

// The page of one snapshot, from a registry of its own.
std::string render_prometheus(const MonitorSnapshot& s, const PrometheusLimits& limits = {});

}  // namespace farm
