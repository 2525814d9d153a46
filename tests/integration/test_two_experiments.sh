#!/usr/bin/env bash
# Two experiments on one DDS domain: a SAC learner (pendulum) and a PPO learner (cart-pole), each
# with a worker bound to it by --experiment, and one worker without --experiment that must stay
# with the first experiment it saw. Both learners end normally on their time limit; each learner's
# roster and summary hold only its own workers, with nothing lost or duplicate, and the unbound
# worker says once that it ignores the other experiment.
#   tests/integration/test_two_experiments.sh LEARNER WORKER
set -uo pipefail
learner=$(readlink -f "$1") worker=$(readlink -f "$2")
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init twoexp 97

sac=it_twoexp_sac ppo=it_twoexp_ppo
cat >"$dir/sac.txtpb" <<CFG
experiment_id: "$sac"
task { name: "pendulum" }
sac { hidden: 32 hidden: 32 learning_starts: 100 batch_size: 64 publish_every_updates: 5 }
worker { envs_per_worker: 4 steps_per_batch: 25 max_batches_per_version: 4 }
eval { episodes: 2 every_seconds: 600 final_episodes: 2 }
checkpoint_every_seconds: 600
log_every_seconds: 2
stop { max_seconds: 16 }
CFG
cat >"$dir/ppo.txtpb" <<CFG
experiment_id: "$ppo"
algorithm: "ppo"
task { name: "cartpole" cartpole { control_substeps: 2 max_episode_steps: 100 } }
ppo { hidden: 16 hidden: 16 steps_per_fit: 1024 mini_batch_size: 256 eval_every_fits: 1000 }
worker { envs_per_worker: 8 steps_per_batch: 32 max_batches_per_version: 4 }
eval { episodes: 2 final_episodes: 2 }
checkpoint_every_seconds: 600
log_every_seconds: 2
stop { max_seconds: 12 }
CFG

# wait_exit PID SECONDS: the process's exit status, or 124 (and the process killed) after SECONDS.
wait_exit() {
  for _ in $(seq $(($2 * 5))); do
    kill -0 "$1" 2>/dev/null || { wait "$1"; return $?; }
    sleep 0.2
  done
  kill -9 "$1" 2>/dev/null
  wait "$1" 2>/dev/null
  return 124
}

start=$(date +%s)
"$learner" --config "$dir/sac.txtpb" --run-dir "$dir/sac" --domain $domain >"$dir/sac.log" 2>&1 & sac_pid=$!
pids+=($sac_pid)
wait_event "$dir/sac" start 20 || fail "the SAC learner did not start: $(tail -5 "$dir/sac.log")"
# The unbound worker sees only the SAC experiment at first: that one is its experiment for good.
"$worker" --domain $domain --id free --events "$dir/free.jsonl" >"$dir/free.log" 2>&1 & free_pid=$!
pids+=($free_pid)
wait_worker_event "$dir/free.jsonl" joined 20 "\"experiment_id\":\"$sac\"" || fail "the unbound worker did not join '$sac'"
"$learner" --config "$dir/ppo.txtpb" --run-dir "$dir/ppo" --domain $domain >"$dir/ppo.log" 2>&1 & ppo_pid=$!
pids+=($ppo_pid)
"$worker" --domain $domain --id sw --experiment $sac --events "$dir/sw.jsonl" >"$dir/sw.log" 2>&1 & sw_pid=$!
pids+=($sw_pid)
"$worker" --domain $domain --id pw --experiment $ppo --events "$dir/pw.jsonl" >"$dir/pw.log" 2>&1 & pw_pid=$!
pids+=($pw_pid)

wait_exit $sac_pid 40; rc=$?
[ $rc = 0 ] || fail "the SAC learner exited $rc: $(tail -5 "$dir/sac.log")"
wait_exit $ppo_pid 30; rc=$?
[ $rc = 0 ] || fail "the PPO learner exited $rc: $(tail -5 "$dir/ppo.log")"
for w in free sw pw; do
  pid_var=${w}_pid
  wait_exit ${!pid_var} 20; rc=$?
  [ $rc = 0 ] || fail "worker $w exited $rc: $(tail -3 "$dir/$w.log")"
done

# check_learner NAME WORKERS...: its summary has one closed stream per worker named, with nothing
# lost or duplicate, and its log names no other worker.
check_learner() {
  local name=$1; shift
  local run="$dir/$name"
  summary_of "$run" 's["reason"]' >/dev/null || { fail "$name: no summary event"; return; }
  echo "--- $name summary"; cat "$run/summary.txt"
  local ids
  ids=$(summary_of "$run" '" ".join(sorted(f["worker_id"] for f in s["streams"]))')
  [ "$ids" = "$(printf '%s\n' "$@" | sort | tr '\n' ' ' | sed 's/ $//')" ] || fail "$name: summary has workers '$ids', expected '$*'"
  [ "$(summary_of "$run" 'all(f["lost"] + f["duplicate"] + f["invalid"] == 0 and f["closed"] for f in s["streams"])')" = true ] ||
    fail "$name: a stream lost batches or was not closed: $(summary_of "$run" 's["streams"]')"
  summary_batches_whole "$run" || fail "$name: batches lost, duplicate or invalid: $(events "$run" summary)"
  [ "$(summary_of "$run" 's["batches_other_experiments"]')" -gt 0 ] ||
    fail "$name: the other experiment's batches are not counted apart"
  # The live workers of every progress event (what PPO divides its quota by) are its own only.
  live=$(grep '"event":"progress"' "$dir/$name/events.jsonl" | grep -o '"workers":[0-9]*' | cut -d: -f2 | sort -un |
    tr '\n' ' ')
  [ -n "$live" ] || fail "$name: no progress event gives its live workers"
  for n in $live; do [ "$n" -le $# ] || fail "$name: counted more than its $# workers live: $live"; done
  for w in free sw pw; do
    printf '%s\n' "$@" | grep -qx "$w" && continue
    events "$dir/$name" worker | grep -qF "\"worker_id\":\"$w\"" &&
      fail "$name: its roster counts worker $w of the other experiment"
  done
}
check_learner sac free sw
check_learner ppo pw

# Each worker stayed with its experiment; the unbound one noted the other experiment once.
for w in free sw; do
  worker_events "$dir/$w.jsonl" joined | grep -qF "\"experiment_id\":\"$ppo\"" && fail "worker $w joined '$ppo'"
done
worker_events "$dir/pw.jsonl" joined | grep -qF "\"experiment_id\":\"$sac\"" && fail "worker pw joined '$sac'"
n=$(worker_events "$dir/free.jsonl" foreign | grep -cF "\"experiment_id\":\"$ppo\"")
[ "$n" = 1 ] || fail "worker free noted the experiment '$ppo' $n times, expected once"
echo "--- worker free"; cat "$dir/free.log"
echo "run time $(($(date +%s) - start)) s"

farm_test_end "two experiments on one domain"
