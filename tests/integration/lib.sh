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
  local e v
  read -r e v < <(csv_elapsed_last "$1" batches_ok)
  echo "${v:-0}"
}

# The events of one kind (RUN_DIR/events.jsonl, the learner's record for programs), one JSON object
# a line as the learner writes them (keys sorted, no spaces).  events RUN_DIR KIND
events() { grep -F "\"event\":\"$2\"" "$1/events.jsonl" 2>/dev/null; }

# What the run's summary event says (the last "summary" event of RUN/events.jsonl), by a Python
# expression over the event as s, with w(ID) the list of worker ID's streams in it (one a session);
# printed as event_of prints.  summary_of RUN 's["batches_lost"], s["batches_invalid"]'
summary_of() { event_of "$1/events.jsonl" summary "$2"; }

# The events of one kind in a worker's events file (farm-worker --events FILE), one JSON object a
# line (keys sorted, no spaces).  worker_events FILE KIND
worker_events() { grep -F "\"event\":\"$2\"" "$1" 2>/dev/null; }

# Polls a worker's events file every 0.2 s until it holds an event of KIND (with TEXT in its line,
# a fixed string, where given); false after SECONDS.  wait_worker_event FILE KIND SECONDS [TEXT]
wait_worker_event() {
  for _ in $(seq $(($3 * 5))); do worker_events "$1" "$2" | grep -qF -- "${4:-}" && return 0; sleep 0.2; done
  return 1
}

# The events of one kind of an events file, for the readers below: read(FILE, KIND), in order; a
# line that is not JSON (one cut short by a full disk) is skipped.
_read_events_py='
import json, sys
def read(path, kind):
    out = []
    for line in open(path, errors="replace"):
        try:
            e = json.loads(line)
        except ValueError:
            continue
        if e.get("event") == kind:
            out.append(e)
    return out
'

# What the last event of KIND in an events file (a worker's --events FILE, or RUN/events.jsonl)
# says, by a Python expression over it as e (also s; w(ID): the streams of worker ID in a summary
# event). A tuple prints space-separated; true/false/null, lists and objects as JSON. Prints nothing
# and is false when the file has no such event.  event_of FILE KIND EXPR
event_of() {
  python3 -c "$_read_events_py"'
found = read(sys.argv[1], sys.argv[2])
if not found:
    sys.exit(1)
e = s = found[-1]
w = lambda i: [x for x in s.get("streams", []) if x["worker_id"] == i]
v = eval(sys.argv[3])
out = lambda x: json.dumps(x) if x is None or isinstance(x, (bool, list, dict)) else str(x)
print(" ".join(out(x) for x in v) if isinstance(v, tuple) else out(v))
' "$1" "$2" "$3" 2>/dev/null
}

# Whether an events file holds an event of KIND whose fields hold each KEY=VALUE given (VALUE as
# JSON: 5, "ev-1", true).  has_event FILE KIND KEY=VALUE...
has_event() {
  python3 -c "$_read_events_py"'
want = {k: json.loads(v) for k, v in (a.split("=", 1) for a in sys.argv[3:])}
sys.exit(not any(all(e.get(k) == v for k, v in want.items()) for e in read(sys.argv[1], sys.argv[2])))
' "$@" 2>/dev/null
}

# Polls RUN/events.jsonl every 0.2 s until it holds an event of KIND (with TEXT in its line, a fixed
# string, where given); false after SECONDS.  wait_event RUN KIND SECONDS [TEXT]
wait_event() {
  for _ in $(seq $(($3 * 5))); do events "$1" "$2" | grep -qF -- "${4:-}" && return 0; sleep 0.2; done
  return 1
}

# Whether the run's summary counts batches accepted (at least MIN, 1 without it) and none lost,
# duplicated or invalid.  summary_batches_whole RUN [MIN]
summary_batches_whole() {
  [ "$(summary_of "$1" 's["batches_ok"] >= '"${2:-1}"' and s["batches_lost"] + s["batches_duplicate"] + s["batches_invalid"] == 0')" = true ]
}

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

# Polls an events file (RUN/events.jsonl, a worker's or farm_intruder's --events FILE) every 0.2 s
# until it holds an event of KIND whose fields hold each KEY=VALUE given (VALUE as JSON, as
# has_event takes them); false after SECONDS.  wait_has_event FILE KIND SECONDS [KEY=VALUE...]
wait_has_event() {
  local file=$1 kind=$2 seconds=$3
  shift 3
  for _ in $(seq $((seconds * 5))); do has_event "$file" "$kind" "$@" && return 0; sleep 0.2; done
  return 1
}

# Whether two events files (farm-play's or farm-mclari-eval's --events, say) hold the same events
# of KIND, in the same order, with the same fields apart from elapsed_s; prints the first that
# differs when not.  events_same_but_time FILE1 FILE2 KIND
events_same_but_time() {
  python3 -c "$_read_events_py"'
a, b = ([{k: v for k, v in e.items() if k != "elapsed_s"} for e in read(p, sys.argv[3])] for p in sys.argv[1:3])
for x, y in zip(a, b):
    if x != y:
        print("%s: %s\n%s: %s" % (sys.argv[1], json.dumps(x), sys.argv[2], json.dumps(y)))
        break
if len(a) != len(b):
    print("%d %s events in %s, %d in %s" % (len(a), sys.argv[3], sys.argv[1], len(b), sys.argv[2]))
sys.exit(a != b or not a)
' "$@"
}

# elapsed_s and COLUMN at the last row of RUN/learner.csv ("0 0" before the first).  csv_elapsed_last RUN COLUMN
csv_elapsed_last() {
  [ -f "$1/learner.csv" ] || { echo 0 0; return; }
  awk -F, -v want="$2" 'NR == 1 { for (i = 1; i <= NF; ++i) { if ($i == want) c = i; if ($i == "elapsed_s") e = i }; next }
                        c { le = $e; lv = $c } END { print le + 0, lv + 0 }' "$1/learner.csv" 2>/dev/null || echo 0 0
}

# An attack's cost, measured against the same learner's rate with the attack paused: ROUNDS times,
# the attacking process PID stopped (SIGSTOP) for SECONDS, then running (SIGCONT) for SECONDS, each
# window measured from 0.5 s after the switch. Sets quiet_rate and attack_rate: COLUMN of
# RUN/learner.csv per second over all stopped windows and over all running windows together. A
# shared 2-core machine moves a learner's rate by more than a tenth on its own for tens of seconds;
# alternating short windows puts such a swing on both sides alike. Leaves PID running.
#   alternate_attack PID RUN COLUMN ROUNDS SECONDS
alternate_attack() {
  local pid=$1 run=$2 col=$3 rounds=$4 secs=$5 r phase e1 v1 e2 v2 windows=""
  for r in $(seq "$rounds"); do
    for phase in quiet attack; do
      if [ $phase = quiet ]; then kill -STOP "$pid" 2>/dev/null; else kill -CONT "$pid" 2>/dev/null; fi
      sleep 0.5
      read -r e1 v1 < <(csv_elapsed_last "$run" "$col")
      sleep "$secs"
      read -r e2 v2 < <(csv_elapsed_last "$run" "$col")
      windows+="$phase $e1 $v1 $e2 $v2"$'\n'
    done
  done
  kill -CONT "$pid" 2>/dev/null
  read -r quiet_rate attack_rate < <(awk '{ t[$1] += $4 - $2; v[$1] += $5 - $3 }
    END { printf "%.0f %.0f\n", (t["quiet"] > 0 ? v["quiet"] / t["quiet"] : 0), (t["attack"] > 0 ? v["attack"] / t["attack"] : 0) }' <<<"$windows")
}

# Waits for process PID (a child of this shell) to end, at most SECONDS; returns its exit status, or
# 124 when it still runs then (left running, for the test's cleanup).  wait_pid PID SECONDS
wait_pid() {
  for _ in $(seq $(($2 * 5))); do kill -0 "$1" 2>/dev/null || break; sleep 0.2; done
  kill -0 "$1" 2>/dev/null && return 124
  wait "$1"
}
