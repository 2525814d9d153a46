#!/usr/bin/env bash
# A run that ends on an env step limit before its first evaluation says so, in its log and in its
# summary (a step limit comes sooner the more workers there are); a run that was evaluated before
# the same limit does not.
#   tests/integration/test_stop_rules.sh LEARNER WORKER
set -uo pipefail
learner=$(readlink -f "$1") worker=$(readlink -f "$2")
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init stop 171

# run NAME EVAL_EVERY_SECONDS: a pendulum learner with a 100,000-step limit and one worker.
run() {
  cat >"$dir/$1.txtpb" <<CFG
experiment_id: "it_stop_$1"
task { name: "pendulum" }
sac { hidden: 32 hidden: 32 learning_starts: 100 batch_size: 64 publish_every_updates: 5 }
worker { envs_per_worker: 4 steps_per_batch: 25 max_batches_per_version: 4 }
eval { episodes: 2 every_seconds: $2 final_episodes: 2 }
checkpoint_every_seconds: 600
log_every_seconds: 1
stop { max_env_steps: 100000 max_seconds: 120 }
CFG
  "$learner" --config "$dir/$1.txtpb" --run-dir "$dir/$1" --domain $domain >"$dir/$1.log" 2>&1 & local lp=$!
  pids+=($lp)
  "$worker" --domain $domain --id sw >"$dir/$1-worker.log" 2>&1 & pids+=($!)
  wait $lp; local rc=$?
  [ $rc = 0 ] || fail "$1: learner exited $rc: $(tail -5 "$dir/$1.log")"
  [ "$(summary_of "$dir/$1" 's["reason"]')" = "env step limit 100000" ] ||
    fail "$1: did not stop on the step limit: $(events "$dir/$1" summary)"
}

run unevaluated 600
cat "$dir/unevaluated/summary.txt"
note="the run stopped on its env step limit before its first evaluation (eval.every_seconds 600)"
summary_of "$dir/unevaluated" 's["note"]' | grep -qF "$note" || fail "no note in the summary: $(events "$dir/unevaluated" summary)"

run evaluated 0.2
events "$dir/evaluated" evaluation | grep -cF '"label":"eval"' >/dev/null || fail "evaluated: no evaluation before the limit"
[ "$(summary_of "$dir/evaluated" 's["note"] == ""')" = true ] ||
  fail "evaluated: a note where the run was evaluated: $(events "$dir/evaluated" summary)"

farm_test_end
