# What the shell integration tests share; source it, then call farm_test_init.
#   source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"; farm_test_init NAME OFFSET
# gives: $dir (a fresh folder, removed at exit when the test passed and FARM_KEEP_LOGS is unset),
# $domain (a DDS domain of its own: 20 + (pid + OFFSET) mod 200), pids=() (killed at exit),
# failed=0, fail MESSAGE, wait_text FILE TEXT SECONDS and farm_test_end [WHAT]. A test that must
# undo something before its folder goes (a mount) defines before_cleanup.

farm_test_init() {
  dir=$(mktemp -d "/tmp/farm-$1-test-XXXXXX")
  domain=$((20 + ($$ + $2) % 200))
  pids=()
  failed=0
  trap farm_test_cleanup EXIT
}

fail() { echo "FAIL: $*"; failed=1; }

farm_test_cleanup() {
  for p in "${pids[@]}"; do kill -9 "$p" 2>/dev/null; done
  wait 2>/dev/null
  if declare -F before_cleanup >/dev/null; then before_cleanup; fi
  if [ "$failed" = 0 ] && [ -z "${FARM_KEEP_LOGS:-}" ]; then rm -rf "$dir"; else echo "logs kept in $dir"; fi
}

# Polls FILE every 0.2 s until it holds TEXT (a grep pattern); false after SECONDS.
wait_text() {
  for _ in $(seq $(($3 * 5))); do grep -q "$2" "$1" 2>/dev/null && return 0; sleep 0.2; done
  return 1
}

farm_test_end() {
  [ "$failed" = 0 ] && echo "PASS${1:+: $1}"
  exit "$failed"
}

# Writes FILE: SOURCE_DIR/deploy/configs/pendulum_sac.txtpb with experiment id ID, its top-level
# stop block replaced by `stop { STOP }` and logs every second; fails the test if no stop block was
# replaced.  pendulum_config SOURCE_DIR ID 'STOP' FILE
pendulum_config() {
  awk -v stop="$3" '/^stop \{/ { print "stop { " stop " }"; skip = 1; next } skip { if ($0 ~ /^\}/) skip = 0; next } { print }' \
    "$1/deploy/configs/pendulum_sac.txtpb" |
    sed -e "s/^experiment_id: .*/experiment_id: \"$2\"/" -e 's/^log_every_seconds: .*/log_every_seconds: 1/' >"$4"
  grep -q "^stop { $3 }" "$4" || fail "test set-up: no stop block replaced in $4"
}

# The batches a learner has accepted so far, from the last row of RUN_DIR/learner.csv (column
# batches_ok); 0 before the first row.  batches_ok RUN_DIR
batches_ok() {
  awk -F, 'NR == 1 { for (i = 1; i <= NF; ++i) if ($i == "batches_ok") c = i; next } c { v = $c } END { print v + 0 }' \
    "$1/learner.csv" 2>/dev/null
}

# The events of one kind (RUN_DIR/events.jsonl, the learner's record for programs), one JSON object
# a line as the learner writes them (keys sorted, no spaces).  events RUN_DIR KIND
events() { grep -F "\"event\":\"$2\"" "$1/events.jsonl" 2>/dev/null; }

# A process's peak resident memory in kB (VmHWM), or nothing once it has ended.  peak_kb PID
peak_kb() { sed -n 's/^VmHWM:[[:space:]]*\([0-9]*\) kB/\1/p' "/proc/$1/status" 2>/dev/null; }

# Starts a pendulum learner (config $dir/ID.txtpb with `stop { STOP }`, run folder $dir/run, log
# $dir/learner.log) and one worker WORKER of 4 envs (log $dir/worker.log); sets lp and wp to their
# pids, waits until the learner has taken a batch and 1 s more, and sets before to its batches_ok.
#   start_pendulum_pair SOURCE_DIR LEARNER WORKER_BIN ID 'STOP' WORKER
start_pendulum_pair() {
  pendulum_config "$1" "$4" "$5" "$dir/$4.txtpb"
  "$2" --config "$dir/$4.txtpb" --run-dir "$dir/run" --domain $domain >"$dir/learner.log" 2>&1 & lp=$!; pids+=($lp)
  "$3" --domain $domain --id "$6" --envs 4 >"$dir/worker.log" 2>&1 & wp=$!; pids+=($wp)
  for _ in $(seq 150); do [ "$(batches_ok "$dir/run")" -gt 0 ] && break; sleep 0.2; done
  sleep 1
  before=$(batches_ok "$dir/run")
  [ "$before" -gt 0 ] || fail "no batch of the worker reached the learner: $(tail -3 "$dir/worker.log")"
}
