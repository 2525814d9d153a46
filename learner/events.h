// The learner's record for programs: RUN/events.jsonl (an EventLog, common/event_log.h), one JSON
// object a line, each with "event" (its kind) and "elapsed_s" (seconds of the run, as learner.csv
// counts them). Kinds:
//   start       the run's experiment, task, algorithm, domain and DDS Security folder ("" without);
//               written as the learner starts to wait for workers
//   progress    one per learner.csv row: the fields of its statistics record (stats_record.h)
//               under the CSV's column names, the live workers throttled or in backpressure
//               (workers_throttled, workers_backpressure) among them
//   ingest      from the ingest thread, at most once a second while batches arrive: its counters
//               (batches_ok, batches_lost, batches_duplicate, batches_invalid, env_steps, queued)
//   refusal     a batch, batch sample or heartbeat refused (the first ones; the ingest counters
//               count every batch)
//   worker      a worker joined, came back, built its environments ("sized": envs known) or was
//               marked dead (roster; bounded as its log lines)
//   ask         a part of an evaluation asked of a worker: request_id, worker_id, label,
//               policy_version, episodes, part of parts, total_episodes, attempt (2: asked again
//               after its first worker was lost), first_episode, seed
//   eval_waits  an evaluation that waits for a live worker (none now): label, policy_version
//   eval_lost   a part counted lost: request_id, worker_id, label, part, attempt, why
//   eval_not_answered  at the end, one not answered before the run ended: label, policy_version,
//               worker_id ("" when no live worker took it), waited_s
//   answer      one worker's answer to a part of an evaluation: who, its episodes and seconds
//   busy        a training pass of the loop that took at least 0.1 s (a PPO fit): its seconds, and
//               the batches and env steps the ingest thread accepted meanwhile (queued: held for
//               the loop at its end)
//   evaluation  an evaluation's report: label, policy_version, episodes, mean, min, max, metrics
//   grants      the worker grants read again on SIGHUP (security): what changed, who is granted
//   best        a new best policy kept in RUN/best
//   checkpoint  a checkpoint written (ok) or failed (error)
//   stop        why the run stopped
//   summary     the end-of-run figures of summary.txt: why it stopped, counts, evaluations, the best,
//               the note on a stop before any evaluation ("" when none), and the worker streams
//               (streams: worker_id, session, received, last_sequence, lost, duplicate, invalid,
//               closed; as many as summary.txt lists); the round pacing's figures besides (fits,
//               batches_stale, quota_top_ups, mode, max_policy_lag, steps_fitted, steps_stale,
//               steps_held, steps_fitted_by_lag: steps by versions behind the fitted one)
// The human log stays what it is; tests, tools/seeds.py and the benchmark scripts read this.
#pragma once

#include "event_log.h"
