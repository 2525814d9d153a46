#!/usr/bin/env bash
# Invented worker streams and heartbeats neither lock a worker out nor grow the learner. Before any
# worker, a participant sends 5,000 one-step batches, each under an invented worker id and session
# (more streams than the learner keeps open), and 10,000 heartbeats of invented sessions with
# 60,000-character host names, then 3 heartbeats of 100 MB host names each, which the learner refuses
# before taking memory for them (a refusal event says so). A real worker that joins after it trains: its stream is accepted
# whole, nothing of it lost or invalid. The learner's summary keeps the open streams at the bound,
# its peak memory stays within 250 MiB of a run without the flood (measured in the same test; the heartbeats alone carry 600 MB of host names), and its log stays
# small (the roster writes a bounded number of lines per 10 s).
#   tests/integration/test_account_flood.sh LEARNER WORKER INTRUDER SOURCE_DIR
set -uo pipefail
learner=$(readlink -f "$1") worker=$(readlink -f "$2") intruder=$(readlink -f "$3") src=$(readlink -f "$4")
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init account-flood 139

pendulum_config "$src" it_flood "max_seconds: 20" "$dir/flood.txtpb"

run() {  # NAME FLOOD(0/1): one learner and, after the flood if any, one worker; sets peak (kB)
  local name=$1 flood=$2 lp p
  peak=0
  "$learner" --config "$dir/flood.txtpb" --run-dir "$dir/$name" --domain $domain >"$dir/$name.log" 2>&1 & lp=$!; pids+=($lp)
  if [ "$flood" = 1 ]; then
    "$intruder" --domain $domain --experiment it_flood --id flood --seconds 1 --flood-streams 5000 \
      --flood-heartbeats 10000 --status-host-bytes 60000 >"$dir/intruder.log" 2>&1 ||
      fail "the intruder did not run: $(tail -2 "$dir/intruder.log")"
    "$intruder" --domain $domain --experiment it_flood --id bigbeat --seconds 4 --flood-heartbeats 3 \
      --status-host-bytes 100000000 >"$dir/bigbeat.log" 2>&1 || fail "the intruder did not run: $(tail -2 "$dir/bigbeat.log")"
  fi
  "$worker" --domain $domain --id fw --envs 4 >"$dir/$name-worker.log" 2>&1 & pids+=($!)
  while kill -0 $lp 2>/dev/null; do p=$(peak_kb $lp); [ -n "$p" ] && peak=$p; sleep 0.5; done
  wait $lp || fail "the $name learner exited with $?: $(tail -3 "$dir/$name.log")"
}
run plain 0
base_peak=$peak
domain=$((domain + 1))
run flooded 1
flood_peak=$peak
run_dir="$dir/flooded"
summary_of "$run_dir" 's["reason"]' >/dev/null || { fail "no summary event of the flooded run"; farm_test_end; }
# The real worker's stream: whole (every sequence number from 0 received), nothing lost or refused.
read -r got last lost invalid < <(summary_of "$run_dir" 'tuple(x for f in w("fw") for x in (f["received"], f["last_sequence"], f["lost"], f["invalid"]))')
line="received ${got:-none} of sequence 0..${last:-none}, lost ${lost:-none}, invalid ${invalid:-none}"
[ "${got:-0}" -gt 0 ] || fail "the real worker's batches were not taken after the flood: $line"
[ "${lost:-1}" = 0 ] && [ "${invalid:-1}" = 0 ] || fail "the real worker's stream lost or had refused batches: $line"
[ "${got:-0}" = "$(( ${last:-0} + 1 ))" ] || fail "the real worker's stream is not whole: $line"
read -r open retired listed < <(summary_of "$run_dir" 's["streams_open"], s["streams_retired"], len(s["streams"])')
[ -n "$open" ] && [ "$open" -le 4096 ] && [ "${retired:-0}" -ge 500 ] ||
  fail "open streams not held at the bound: ${open:-none} open, ${retired:-none} retired"
[ "${listed:-71}" -le 70 ] || fail "the summary lists $listed streams"
events "$dir/flooded" refusal | grep -F '"what":"heartbeat sample"' | grep -c '"count":[1-9]' >/dev/null ||
  fail "no refusal of the 100 MB heartbeats: $(events "$dir/flooded" refusal | head -5)"
log_bytes=$(stat -c %s "$dir/flooded.log")
[ "$log_bytes" -lt 200000 ] || fail "the flooded learner's log is $log_bytes bytes"
[ "$flood_peak" -lt $((base_peak + 256000)) ] || fail "peak memory ${flood_peak} kB with the flood, ${base_peak} kB without"
farm_test_end "real worker: $got batches, lost 0; streams $open open, $retired retired; log $log_bytes bytes; peak ${flood_peak} kB (${base_peak} kB without the flood); $(tail -1 "$dir/intruder.log")"
