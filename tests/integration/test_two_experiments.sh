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
wait_text "$dir/sac.log" "waiting for workers" 20 || fail "the SAC learner did not start: $(tail -5 "$dir/sac.log")"
# The unbound worker sees only the SAC experiment at first: that one is its experiment for good.
"$worker" --domain $domain --id free >"$dir/free.log" 2>&1 & free_pid=$!
pids+=($free_pid)
wait_text "$dir/free.log" "joined experiment '$sac'" 20 || fail "the unbound worker did not join '$sac'"
"$learner" --config "$dir/ppo.txtpb" --run-dir "$dir/ppo" --domain $domain >"$dir/ppo.log" 2>&1 & ppo_pid=$!
pids+=($ppo_pid)
"$worker" --domain $domain --id sw --experiment $sac >"$dir/sw.log" 2>&1 & sw_pid=$!
pids+=($sw_pid)
"$worker" --domain $domain --id pw --experiment $ppo >"$dir/pw.log" 2>&1 & pw_pid=$!
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
  local summary="$dir/$name/summary.txt"
  [ -f "$summary" ] || { fail "$name: no summary"; return; }
  echo "--- $name summary"; cat "$summary"
  local ids
  ids=$(grep '^worker ' "$summary" | awk '{print $2}' | sort | tr '\n' ' ')
  [ "$ids" = "$(printf '%s\n' "$@" | sort | tr '\n' ' ')" ] || fail "$name: summary has workers '$ids', expected '$*'"
  grep '^worker ' "$summary" | grep -v ', lost 0, duplicate 0, invalid 0, stream closed' |
    while read -r line; do echo "FAIL: $name: $line"; done | grep . && failed=1
  grep -q '^batches .* lost 0, duplicate 0, invalid 0' "$summary" ||
    fail "$name: batches lost, duplicate or invalid: $(grep '^batches' "$summary")"
  grep -q '^other experiments [1-9][0-9]* batches of other experiments on the domain, not used' "$summary" ||
    fail "$name: the other experiment's batches are not counted apart"
  # The live workers of every progress event (what PPO divides its quota by) are its own only.
  live=$(grep '"event":"progress"' "$dir/$name/events.jsonl" | grep -o '"workers":[0-9]*' | cut -d: -f2 | sort -un |
    tr '\n' ' ')
  [ -n "$live" ] || fail "$name: no progress event gives its live workers"
  for n in $live; do [ "$n" -le $# ] || fail "$name: counted more than its $# workers live: $live"; done
  for w in free sw pw; do
    printf '%s\n' "$@" | grep -qx "$w" && continue
    grep -q "worker $w on [^ ]* \(joined\|runs\|is back\|silent\)" "$dir/$name.log" &&
      fail "$name: its roster counts worker $w of the other experiment"
  done
}
check_learner sac free sw
check_learner ppo pw

# Each worker stayed with its experiment; the unbound one noted the other experiment once.
for w in free sw; do
  grep -q "joined experiment '$ppo'" "$dir/$w.log" && fail "worker $w joined '$ppo'"
done
grep -q "joined experiment '$sac'" "$dir/pw.log" && fail "worker pw joined '$sac'"
n=$(grep -c "ignores experiment '$ppo'" "$dir/free.log")
[ "$n" = 1 ] || fail "worker free noted the experiment '$ppo' $n times, expected once"
echo "--- worker free"; cat "$dir/free.log"
echo "run time $(($(date +%s) - start)) s"

farm_test_end "two experiments on one domain"
