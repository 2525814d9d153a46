#!/usr/bin/env bash
# An evaluation answer counts only from the participant asked. A learner (pendulum, stop at an
# evaluation return of -5, which 25 s of training does not reach) and one worker; a participant
# that is not that worker answers every evaluation request the moment it appears, every field
# copied from the request and the worker's heartbeats, each episode 200 steps with a return of -1
# (within what the task can give). The learner's summary shows it: the run ends at its time limit,
# not at the target; the kept best is the real worker's; the forgeries are counted invalid and the
# real answers used; no batch lost or invalid.
#   tests/integration/test_eval_forgery.sh LEARNER WORKER INTRUDER SOURCE_DIR
set -uo pipefail
learner=$(readlink -f "$1") worker=$(readlink -f "$2") intruder=$(readlink -f "$3") src=$(readlink -f "$4")
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init eval-forgery 137

awk '/^stop \{/ { print "stop { target_eval_return: -5 max_seconds: 25 }"; skip = 1; next }
     skip { if ($0 ~ /^\}/) skip = 0; next }
     /^eval \{/ { print "eval { episodes: 4 every_seconds: 4 final_episodes: 4 }"; eskip = 1; next }
     eskip { if ($0 ~ /^\}/) eskip = 0; next } { print }' \
  "$src/deploy/configs/pendulum_sac.txtpb" | sed -e 's/^experiment_id: .*/experiment_id: "it_forge"/' >"$dir/forge.txtpb"
grep -q '^stop { target_eval_return: -5' "$dir/forge.txtpb" || fail "test set-up: no stop block replaced"
grep -q '^eval { episodes: 4' "$dir/forge.txtpb" || fail "test set-up: no eval block replaced"
"$intruder" --domain $domain --experiment it_forge --id forger --seconds 40 --forge-answers -1 --forge-length 200 \
  --forge-metrics 1 >"$dir/forger.log" 2>&1 & pids+=($!)
"$learner" --config "$dir/forge.txtpb" --run-dir "$dir/run" --domain $domain >"$dir/learner.log" 2>&1 & lp=$!; pids+=($lp)
"$worker" --domain $domain --id fw --envs 4 >"$dir/worker.log" 2>&1 & pids+=($!)
wait $lp; lrc=$?
[ $lrc = 0 ] || fail "the learner exited with $lrc: $(tail -5 "$dir/learner.log")"
read -r timed asked answered invalid best < <(summary_of "$dir/run" 's["reason"].startswith("time limit "), s["evals_asked"], s["evals_answered"], s["evals_invalid"], s["best_eval"]')
[ -n "${timed:-}" ] || { fail "no summary event"; farm_test_end; }
[ "$timed" = true ] || fail "the run did not end at its time limit: $(events "$dir/run" stop)"
[ "${answered:-0}" -ge 1 ] || fail "no real answer was used: asked $asked, answered $answered, invalid $invalid"
[ "${invalid:-0}" -ge 1 ] || fail "no forged answer was refused (did the forger answer?): invalid $invalid; $(tail -1 "$dir/forger.log")"
[ "${best:-null}" != null ] || fail "no best evaluation in the summary event"
awk -v b="${best:-0}" 'BEGIN { exit !(b < -5) }' || fail "the kept best, $best, is better than -5: a forgery's (-1 an episode)"
summary_batches_whole "$dir/run" 0 || fail "batches lost or invalid: $(events "$dir/run" summary)"
farm_test_end "evaluations asked $asked, answered $answered, forgeries refused $invalid; best $best; $(tail -1 "$dir/forger.log")"
