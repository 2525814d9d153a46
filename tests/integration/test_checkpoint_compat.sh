#!/usr/bin/env bash
# Checkpoints written before the learner was split into its farm side and its algorithms still
# resume: a pendulum SAC checkpoint (networks, optimizers, replay buffer, random state) and a
# cart-pole PPO checkpoint from tests/data/checkpoint_v1, each resumed by today's farm-learner with
# one worker to a normal end: the counters go on from the checkpoint, nothing is lost. And a resume
# that would change the discount of multi-step replay rows (sac.n_step 3, then another gamma) is
# refused at start, naming it, with the checkpoint left as it was.
#   tests/integration/test_checkpoint_compat.sh LEARNER WORKER SOURCE_DIR
set -uo pipefail
learner=$(readlink -f "$1") worker=$(readlink -f "$2") data=$(readlink -f "$3")/tests/data/checkpoint_v1
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init compat 177

# resume NAME: the fixture's checkpoint in a fresh run dir, resumed to the config's time limit.
resume() {
  local name=$1 run="$dir/$1"
  mkdir -p "$run" && cp -r "$data/$name/checkpoint" "$run/checkpoint"
  local updates_before
  updates_before=$(sed -n 's/^updates: \([0-9]*\)/\1/p' "$run/checkpoint/manifest.txtpb")
  "$learner" --config "$data/$name.txtpb" --run-dir "$run" --domain $domain --resume >"$dir/$name.log" 2>&1 &
  local lp=$!
  pids+=($lp)
  "$worker" --domain $domain --id compat-$name >"$dir/$name-worker.log" 2>&1 & pids+=($!)
  wait $lp; local rc=$?
  cat "$dir/$name.log" | grep -v "^\[learner\] *[0-9.]*s |" | head -20
  [ $rc = 0 ] || fail "$name: learner exited $rc: $(tail -5 "$dir/$name.log")"
  events "$run" start | tail -1 | grep -q '"resumed":true' || fail "$name: the run's start is not a resume"
  local summary
  summary=$(events "$run" summary | tail -1)
  [ -n "$summary" ] || { fail "$name: no summary event"; return; }
  echo "$summary"
  # updates, then batches ok, lost, duplicate, invalid, from the summary event.
  local figures
  figures=$(echo "$summary" | python3 -c 'import json, sys; e = json.load(sys.stdin)
print(*(e[k] for k in ("updates", "batches_ok", "batches_lost", "batches_duplicate", "batches_invalid")))')
  local updates_after ok lost duplicate invalid
  read -r updates_after ok lost duplicate invalid <<<"$figures"
  [ -n "$updates_before" ] && [ -n "$updates_after" ] && [ "$updates_after" -gt "$updates_before" ] ||
    fail "$name: updates did not go on from the checkpoint's $updates_before: $updates_after"
  [ "${ok:-0}" -gt 0 ] && [ "$lost/$duplicate/$invalid" = 0/0/0 ] ||
    fail "$name: batches not all accounted: ok $ok, lost $lost, duplicate $duplicate, invalid $invalid"
  # The new checkpoint is written in the same layout as the fixture's.
  for f in $(cd "$data/$name/checkpoint" && find . -type f | sort); do
    [ -f "$run/checkpoint/$f" ] || fail "$name: the new checkpoint has no $f"
  done
  # ... and the policy file the fixture predates (the programs that run a trained policy read it).
  [ -s "$run/checkpoint/policy.bin" ] || fail "$name: the new checkpoint has no policy.bin"
}

resume sac
resume ppo

run="$dir/nstep"
sed -e 's/^sac { /sac { n_step: 3 /' -e 's/^stop {.*/stop { max_seconds: 3 }/' "$data/sac.txtpb" >"$dir/nstep.txtpb"
grep -q "n_step: 3" "$dir/nstep.txtpb" && grep -q "max_seconds: 3 }" "$dir/nstep.txtpb" || fail "could not edit the config"
"$learner" --config "$dir/nstep.txtpb" --run-dir "$run" --domain $domain >"$dir/nstep.log" 2>&1 ||
  fail "the n_step run exited $?: $(tail -3 "$dir/nstep.log")"
sed 's/^sac { /sac { gamma: 0.9 /' "$dir/nstep.txtpb" >"$dir/nstep-gamma.txtpb"
before=$(md5sum <"$run/checkpoint/manifest.txtpb")
"$learner" --config "$dir/nstep-gamma.txtpb" --run-dir "$run" --domain $domain --resume >"$dir/nstep-gamma.log" 2>&1 &&
  fail "a resume with another gamma over 3-step rows ran"
events "$run" refusal | grep -F '"what":"resume"' |
  grep -qF "the checkpoint's replay rows sum up to 3 rewards (sac.n_step) discounted with sac.gamma 0.99, this config's gamma is 0.9" ||
  fail "no refusal event names the discount: $(events "$run" refusal; tail -3 "$dir/nstep-gamma.log")"
[ "$(md5sum <"$run/checkpoint/manifest.txtpb")" = "$before" ] || fail "the refused resume changed the checkpoint"
farm_test_end "checkpoints written before the split resume"
