#!/usr/bin/env bash
# Heartbeats are network input, and what they say reaches an operator's terminal: the learner's log
# and farm-monitor's table. A participant sends heartbeats whose worker id, host and last error
# carry terminal escape sequences (an OSC window title ended by BEL, clear-screen, cursor moves) and
# a 60,000-character host. Neither the learner's log nor the monitor's table holds an ESC or BEL
# byte: both print the sequences escaped (\x1b, \x07), and the host cut.
#   tests/integration/test_log_injection.sh LEARNER MONITOR INTRUDER SOURCE_DIR
set -uo pipefail
learner=$(readlink -f "$1") monitor=$(readlink -f "$2") intruder=$(readlink -f "$3") src=$(readlink -f "$4")
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init log-injection 137

cat >"$dir/cfg.txtpb" <<'CFG'
experiment_id: "it_inject"
task { name: "pendulum" }
worker { envs_per_worker: 1 steps_per_batch: 1 max_batches_per_version: 1000 }
log_every_seconds: 1
stop { max_seconds: 12 }
CFG
esc=$'\033' bel=$'\007'
id="evil${esc}]0;owned${bel}${esc}[2J"
host="h${esc}[1;1H$(printf 'x%.0s' $(seq 60000))"
"$learner" --config "$dir/cfg.txtpb" --run-dir "$dir/run" --domain $domain >"$dir/learner.log" 2>&1 & lp=$!; pids+=($lp)
"$intruder" --domain $domain --experiment it_inject --id "$id" --obs 3 --act 1 --seconds 8 --heartbeat 1 \
  --status-host "$host" --status-error "boom${esc}[31m" >"$dir/intruder.log" 2>&1 & pids+=($!)
sleep 4
"$monitor" --once --wait 3 --domain $domain >"$dir/monitor.txt" 2>&1 || fail "farm-monitor --once: $(tail -3 "$dir/monitor.txt")"
wait $lp

for f in learner.log monitor.txt; do
  grep -q "$esc" "$dir/$f" && fail "$f holds an ESC byte"
  grep -q "$bel" "$dir/$f" && fail "$f holds a BEL byte"
  grep -qF 'evil\x1b]0;owned\x07\x1b[2J' "$dir/$f" || fail "$f does not show the worker id escaped"
  grep -qF 'h\x1b[1;1Hxxx' "$dir/$f" || fail "$f does not show the host escaped"
  [ "$(wc -L <"$dir/$f")" -lt 2000 ] || fail "$f has a line of $(wc -L <"$dir/$f") characters: the host was not cut"
done
grep -qF 'boom\x1b[31m' "$dir/learner.log" || fail "learner.log does not show the reported error escaped"
farm_test_end "no ESC or BEL byte in the learner's log or the monitor's table"
