#include "ingest_accounts.h"

namespace farm {

namespace {

void to_record(const WorkerAccount& w, bool retired, config::WorkerAccountRecord* r) {
  r->set_worker_id(w.worker_id);
  r->set_session(w.session);
  r->set_next_sequence(w.next_sequence);
  r->set_received(w.received);
  r->set_lost(w.lost);
  r->set_duplicates(w.duplicates);
  r->set_invalid(w.invalid);
  r->set_env_steps(w.env_steps);
  r->set_ended(w.ended);
  for (uint64_t s : w.missing) r->add_missing(s);
  if (retired) r->set_retired(true);
  if (!w.writer.empty()) r->set_writer(w.writer);
}

WorkerAccount from_record(const config::WorkerAccountRecord& r, double now) {
  WorkerAccount w;
  w.worker_id = r.worker_id();
  w.session = r.session();
  w.next_sequence = r.next_sequence();
  w.received = r.received();
  w.lost = r.lost();
  w.duplicates = r.duplicates();
  w.invalid = r.invalid();
  w.env_steps = r.env_steps();
  w.ended = r.ended();
  w.writer = r.writer();
  w.last_seen = now;
  // As Ingest keeps them: numbers below the next expected one, at most kMaxMissing.
  for (uint64_t s : r.missing())
    if (s < w.next_sequence && w.missing.size() < Ingest::kMaxMissing) w.missing.push_back(s);
  return w;
}

}  // namespace

void accounts_to_manifest(const Ingest& ingest, config::CheckpointManifest& m) {
  m.clear_workers();
  for (const auto& [key, w] : ingest.workers()) to_record(w, false, m.add_workers());
  for (const auto& key : ingest.retired_order()) to_record(ingest.retired_accounts().at(key), true, m.add_workers());
  const auto& c = ingest.counters();
  m.set_batches_ok(c.ok);
  m.set_batches_lost(c.lost);
  m.set_batches_duplicate(c.duplicate);
  m.set_batches_invalid(c.invalid);
  m.set_env_steps(c.env_steps);
}

void accounts_from_manifest(const config::CheckpointManifest& m, Ingest& ingest, double now) {
  std::map<Ingest::Key, WorkerAccount> open;
  std::vector<WorkerAccount> retired;  // oldest retired first, as written
  for (const auto& r : m.workers()) {
    if (r.retired())
      retired.push_back(from_record(r, now));
    else
      open[{r.worker_id(), r.session()}] = from_record(r, now);
  }
  IngestCounters c;
  c.ok = m.batches_ok();
  c.lost = m.batches_lost();
  c.duplicate = m.batches_duplicate();
  c.invalid = m.batches_invalid();
  c.env_steps = m.env_steps();
  ingest.restore(open, retired, c);
}

}  // namespace farm
