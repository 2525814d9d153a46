#!/usr/bin/env bash
# The Fast DDS profiles file given three ways, as the README promises: the standard
# FASTRTPS_DEFAULT_PROFILES_FILE variable alone, the --dds-profiles flag alone, and both naming one
# file. For each way, every program that opens the bus runs for real: a learner with a worker
# (3 envs) to its end with nothing lost, farm-monitor --once seeing the worker, bench_scale with
# one worker (it hands the file to its workers through the variable) and bench_transport (it hands
# the file to its writer through the flag). The join line names the worker's 3 envs, never 0.
# A file without the farm's profiles, or a missing one, is named in the error with where it came
# from.
#   tests/integration/test_profiles_variable.sh LEARNER WORKER MONITOR BENCH_SCALE BENCH_TRANSPORT SOURCE_DIR
set -uo pipefail
learner=$(readlink -f "$1") worker=$(readlink -f "$2") monitor=$(readlink -f "$3")
bench_scale=$(readlink -f "$4") bench_transport=$(readlink -f "$5") src=$(readlink -f "$6")
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init profiles 131

# A copy away from every default place, so only the way under test can name it.
profiles="$dir/my_profiles.xml"
cp "$src/deploy/fastdds_profiles.xml" "$profiles"

cat >"$dir/cfg.txtpb" <<'EOF'
experiment_id: "it_profiles"
seed: 3
task { name: "pendulum" }
sac { hidden: 32 hidden: 32 learning_starts: 200 batch_size: 64 publish_every_updates: 10 }
worker { envs_per_worker: 8 steps_per_batch: 25 max_batches_per_version: 20 }
eval { episodes: 2 every_seconds: 600 final_episodes: 2 }
checkpoint_every_seconds: 600
log_every_seconds: 1
stop { max_seconds: 10 }
EOF

# run_with WAY PROGRAM ARGS...: the program with the profiles file given the WAY (var, flag, both).
run_with() {
  local way=$1; shift
  local prog=$1; shift
  case $way in
    var) FASTRTPS_DEFAULT_PROFILES_FILE="$profiles" "$prog" "$@" ;;
    flag) env -u FASTRTPS_DEFAULT_PROFILES_FILE "$prog" "$@" --dds-profiles "$profiles" ;;
    both) FASTRTPS_DEFAULT_PROFILES_FILE="$profiles" "$prog" "$@" --dds-profiles "$profiles" ;;
  esac
}


for way in var flag both; do
  d=$((domain + ${#way}))
  out="$dir/$way"
  mkdir -p "$out"
  run_with $way "$learner" --config "$dir/cfg.txtpb" --run-dir "$out/run" --domain $d >"$out/learner.log" 2>&1 &
  lp=$!; pids+=($lp)
  run_with $way "$worker" --domain $d --id pw --envs 3 --events "$out/worker.jsonl" >"$out/worker.log" 2>&1 &
  wp=$!; pids+=($wp)
  wait_worker_event "$out/worker.jsonl" joined 30 || fail "$way: worker did not join: $(tail -3 "$out/worker.log")"
  sleep 2
  run_with $way "$monitor" --domain $d --once --wait 10 >"$out/monitor.txt" 2>&1 ||
    fail "$way: farm-monitor --once failed: $(tail -3 "$out/monitor.txt")"
  awk '$2 == "pw"' "$out/monitor.txt" | grep -q . ||
    fail "$way: farm-monitor does not list worker pw: $(cat "$out/monitor.txt")"
  wait $lp; rc=$?
  [ $rc = 0 ] || fail "$way: learner exited $rc: $(tail -5 "$out/learner.log")"
  summary_batches_whole "$out/run" || fail "$way: summary: $(events "$out/run" summary)"
  # The roster's events of the worker: its join, then (once it built them) its 3 envs on 1 thread.
  events "$out/run" worker | grep -F '"worker_id":"pw"' | grep -c '"change":"joined"' >/dev/null ||
    fail "$way: no join event of pw: $(events "$out/run" worker)"
  events "$out/run" worker | grep -F '"worker_id":"pw"' | grep -Eq '"change":"(joined|sized)".*"envs":3,.*"threads":1' ||
    fail "$way: no event gives the worker's 3 envs on 1 thread: $(events "$out/run" worker)"
  kill -INT $wp 2>/dev/null; wait $wp 2>/dev/null

  run_with $way "$bench_scale" --workers 1 --envs 4 --seconds 1 --warmup 1 --domain $d \
    --log-dir "$out/scale" >"$out/scale.txt" 2>&1; rc=$?
  [ $rc = 0 ] && grep -Eq "^ +1 +[0-9]+" "$out/scale.txt" ||
    fail "$way: bench_scale exited $rc: $(tail -5 "$out/scale.txt"; tail -3 "$out"/scale/*.log 2>/dev/null)"
  run_with $way "$bench_transport" --sizes 10000 --seconds 1 --domain $d >"$out/transport.txt" 2>&1; rc=$?
  [ $rc = 0 ] && grep -q "profiles $profiles" "$out/transport.txt" ||
    fail "$way: bench_transport exited $rc: $(tail -5 "$out/transport.txt")"
  echo "$way: learner, worker, monitor, bench_scale and bench_transport ran with $profiles"
done

# A file that lacks the farm's profiles, and a missing one: named, with the way that named them.
cat >"$dir/empty.xml" <<'EOF'
<?xml version="1.0" encoding="UTF-8" ?>
<dds xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <profiles><participant profile_name="someone_else"><rtps/></participant></profiles>
</dds>
EOF
out=$(FASTRTPS_DEFAULT_PROFILES_FILE="$dir/empty.xml" timeout 20 "$worker" --domain $domain 2>&1); rc=$?
[ $rc != 0 ] && grep -q "profile 'farm_participant' missing in $dir/empty.xml" <<<"$out" ||
  fail "variable naming a file without the profiles: rc $rc, '$out'"
out=$(FASTRTPS_DEFAULT_PROFILES_FILE="$dir/none.xml" timeout 20 "$worker" --domain $domain 2>&1); rc=$?
[ $rc != 0 ] && grep -q "DDS profiles file not found: $dir/none.xml (from FASTRTPS_DEFAULT_PROFILES_FILE)" <<<"$out" ||
  fail "variable naming a missing file: rc $rc, '$out'"
# Flag and variable naming different files: the flag's file is used, and the override is said.
out=$(FASTRTPS_DEFAULT_PROFILES_FILE="$dir/empty.xml" timeout 20 "$monitor" --once --wait 1 --domain $domain \
      --dds-profiles "$profiles" 2>&1); rc=$?
[ $rc = 1 ] && grep -q "overrides FASTRTPS_DEFAULT_PROFILES_FILE=$dir/empty.xml" <<<"$out" &&
  grep -q "nothing found on DDS domain" <<<"$out" || fail "flag over a different variable: rc $rc, '$out'"

farm_test_end
