// The farm-monitor snapshot (monitor_snapshot.h) in the Prometheus text exposition format 0.0.4:
// the series farm-monitor --prometheus serves at /metrics. Names, types and labels are listed in
// docs/MONITORING.md; deploy/grafana/farm.json queries them.
//
// Worker ids, hosts and experiment ids come off the bus, where any participant of the domain can
// write them, so label values are bounded (truncated on a UTF-8 boundary), made valid UTF-8 and
// escaped; workers past a bound, or whose bounded labels would repeat another's (which would make
// Prometheus refuse the whole scrape), are left out and counted in farm_monitor_workers_not_exported.
#pragma once

#include <cstddef>
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

// A label value as written between the quotes: at most max_bytes of valid UTF-8 (each invalid byte
// and each control character other than a line feed becomes U+FFFD), backslash, double quote and
// line feed escaped.
std::string prometheus_label_value(const std::string& raw, size_t max_bytes);

// Every series of the snapshot, each family with its # HELP and # TYPE lines.
std::string render_prometheus(const MonitorSnapshot& s, const PrometheusLimits& limits = {});

}  // namespace farm
