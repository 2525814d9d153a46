// The learner's evaluations, run on its workers: each one is split into parts over the live
// workers of the roster (eval.min_episodes_per_worker episodes each at least), each part going to
// the next worker in turn with the policy to evaluate, the networks of that moment kept aside for
// <run dir>/best; each answer is checked (eval_answer.h), and once every part is answered their
// episodes are merged into one report. A part whose worker is marked dead or that is not answered
// in eval.answer_timeout_seconds is counted lost and asked once more of another worker; a part
// lost twice gives up its whole evaluation. Under DDS Security a report is confirmed only when two
// workers answered and agree (confirmation()). The evaluator owns its requests, its snapshots and
// its counts; what ended comes back from poll(), for the learner's loop to hand on. It reaches the
// bus only through its channel (eval_channel.h) and the roster only through the workers it lists,
// so that unit tests drive it without processes or DDS (tests/unit/test_evaluator.cpp).
#pragma once

#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <set>
#include <string>
#include <vector>

#include "eval_channel.h"
#include "events.h"
#include "farm_config.pb.h"
#include "pacing.h"
#include "roster_thread.h"
#include "task_spec.h"

namespace farm {

class Evaluator {
 public:
  using Log = std::function<void(const std::string&)>;
  // The workers of the roster as they are now (live or not), in roster order.
  using Workers = std::function<std::vector<RosterThread::Worker>()>;
  // dir: where the networks of each evaluation are kept while it is out (<run dir>/evaluating).
  // Requests and answers over the bus's evaluation topics, to the workers of `roster`.
  Evaluator(farm::dds::Bus& bus, const config::ExperimentConfig& cfg, const robots::TaskSpec& spec,
            const RosterThread& roster, EventLog& events, Log log, std::string dir);
  // Requests and answers over `channel`, to the workers `workers` lists.
  Evaluator(std::unique_ptr<EvalChannel> channel, const config::ExperimentConfig& cfg, const robots::TaskSpec& spec,
            Workers workers, EventLog& events, Log log, std::string dir);

  // Where set, evaluations go only to workers for which delivered(worker id, participant of its
  // heartbeats) holds: those whose batches the learner has taken.
  using Delivered = std::function<bool(const std::string& worker_id, const std::string& participant)>;
  void only_workers_that_delivered(Delivered delivered) { delivered_ = std::move(delivered); }

  // Asks an evaluation of `policy`; keep_networks(folder) saves the networks it is of there (for a
  // new best). false (said in the log once) when a training evaluation is still out; a final one is
  // always asked.
  bool ask(const PolicyParams& policy, const EvalAsk& ask,
           const std::function<void(const std::string&)>& keep_networks);

  // An evaluation that ended: its report, or none (given_up: a part lost twice, or not answered at
  // the end); snapshot: the folder of its networks as asked ("" if none were kept), which the
  // caller drops (drop_snapshot) once it has used it.
  struct Done {
    EvalAsk ask;
    EvalReport report;
    std::string snapshot;
    bool given_up = false;
  };
  // Takes the answers that arrived, counts lost the requests whose worker died or that timed out
  // (asking them again once), sends the waiting ones; returns the evaluations that ended.
  std::vector<Done> poll();
  // Waits up to `seconds` for an answer.
  void wait(double seconds) { channel_->wait(seconds); }
  // Gives up every evaluation still out (counted lost where it was asked), each said in the log
  // with how long it was waited for; returns them.
  std::vector<Done> give_up_all(double waited_seconds);
  size_t out() const { return out_.size(); }
  static void drop_snapshot(const std::string& dir);
  const std::string& dir() const { return dir_; }

  uint64_t evaluations() const { return evaluations_; }  // evaluations asked (each of one or more parts)
  uint64_t asked() const { return n_.asked; }            // parts sent to workers, retries included
  uint64_t answered() const { return n_.answered; }
  uint64_t lost() const { return n_.lost; }
  uint64_t invalid() const { return n_.invalid; }
  // A resumed run's counts go on from its checkpoint's (parts out then were counted lost there).
  void restore_counts(uint64_t asked, uint64_t answered, uint64_t lost, uint64_t invalid) {
    n_.asked = asked;
    n_.answered = answered;
    n_.lost = lost;
    n_.invalid = invalid;
  }
  // The summary's "evaluations       asked ..." line.
  std::string summary() const;

  static constexpr double kAgreeSigmas = 4.0, kAgreeRelative = 0.05;

 private:
  // One evaluation (one EvalAsk), spread over one or more workers as parts, reported once every
  // part is answered.
  struct Group {
    EvalAsk ask;
    PolicyParams policy;
    std::string snapshot;  // the algorithm's networks when it asked (for best/); "" if not kept
    int parts = 1, parts_left = 1;
    double asked_at = 0;
    std::vector<farm::msg::EvaluationEpisode> episodes;            // of the parts answered so far
    std::map<std::string, std::vector<double>> returns_by_worker;  // the answered parts' returns
  };
  // One part of an evaluation asked of one worker; a lost one is asked once more (attempt 2) under
  // a new id.
  struct Request {
    uint64_t id = 0, seed = 0, worker_session = 0, group = 0;
    int episodes = 0, part = 1, first_episode = 0;
    std::string worker_id, roster_key;  // empty while no live worker could take it
    // The participant of the worker asked (its roster entry's): only an answer it wrote counts.
    std::string writer;
    double asked_at = 0;
    int attempt = 1;
    std::string avoid;  // the worker that lost attempt 1: another one is asked where there is one
    EvalAsk ask;
    bool skips_noted = false;  // a training evaluation skipped while this one is out was logged
  };
  // Under DDS Security a kept best or a stop rests on the word of two workers: an evaluation's
  // parts go to two workers at least where two are ready, and the report is confirmed only when
  // two answered and each pair's mean returns agree within kAgreeSigmas standard errors of the
  // pair's narrower side (plus kAgreeRelative of their size; returns_agree, eval_answer.h). "" when
  // confirmed; else why not.
  std::string confirmation(const Group& group) const;
  // Live workers that have built their environments, in roster order.
  std::vector<RosterThread::Worker> ready_workers() const;
  // Sends r to a live worker of the roster, in turn (another than r.avoid where possible); false
  // when there is none.
  bool send(Request& r);
  // The answer in answer_: checked, merged into its group; a group complete goes to done_.
  void take_answer();
  // A request no worker answered: asked again once, else its evaluation given up.
  void lost(Request r, const std::string& why);
  // The evaluation of a group ended without a report: its other parts' answers are not used.
  void given_up(uint64_t group);
  // Counts a request asked of a worker lost: its id closed, and an eval_lost event (request,
  // worker, attempt, why) so programs can tell each loss apart.
  void count_lost(const Request& r, const std::string& why);
  // Remembers a request id lost or given up (bounded), so an answer that still comes counts late.
  void close_id(uint64_t id);

  std::unique_ptr<EvalChannel> channel_;
  const config::ExperimentConfig& cfg_;
  const robots::TaskSpec& spec_;
  Workers workers_;
  Delivered delivered_;
  EventLog& events_;
  Log log_;
  std::string dir_;
  std::deque<Request> out_;           // parts asked, not yet answered or given up
  std::map<uint64_t, Group> groups_;  // evaluations with parts out
  std::vector<Done> done_;            // ended since the last poll()
  std::set<uint64_t> closed_;         // ids lost or given up, for answers that come late (bounded)
  std::string last_key_;              // the roster key asked last, for the turn
  farm::msg::EvaluationAnswer answer_;
  EvalChannel::Writer answer_writer_;  // who wrote answer_
  uint64_t session_, next_group_ = 0, next_id_ = 0, evaluations_ = 0;
  // Parts asked (retries included), answered, lost, refused as invalid, and answers that came late.
  struct Counts {
    uint64_t asked = 0, answered = 0, lost = 0, invalid = 0, late = 0;
  } n_;
  int rejections_logged_ = 0;
  bool waiting_noted_ = false;
};

}  // namespace farm
