#!/usr/bin/env bash
# tools/seeds.py stopped by a signal (a batch system's time limit) loses nothing: the runs in progress
# write their checkpoints, and `--resume` continues them from there and starts a seed that never
# ran; a run that ended on its own is kept as it is. Checked on the learners' events (start, stop),
# not on prose.
#   test_seeds_resume.sh SOURCE_DIR BUILD_DIR
set -uo pipefail
SRC=$1
BUILD=$2
source "$SRC/tests/integration/lib.sh"
farm_test_init seeds-resume 61
out=$dir/seeds

# The pendulum for 10 s of training, with a target it cannot reach (seeds.py judges the pendulum on it).
pendulum_config "$SRC" it_seeds 'target_eval_return: 1000 max_seconds: 10' "$dir/cfg.txtpb"
# Whether a process whose command line holds TEXT runs (from /proc: no procps needed).
running() {
  local f
  for f in /proc/[0-9]*/cmdline; do tr '\0' ' ' < "$f" 2>/dev/null | grep -qF -- "$1" && return 0; done
  return 1
}

cmd=(python3 "$SRC/tools/seeds.py" "$dir/cfg.txtpb" --workers 1 --parallel 2 --train-only
  --out "$out" --build "$BUILD" --domain "$domain")

# 1. Stopped while seeds 1 and 2 train side by side: exit 130, both stopped with their checkpoints,
#    no learner or worker left behind.
"${cmd[@]}" --seeds 1,2 > "$dir/first.log" 2>&1 &
pids+=($!)
first=$!
for s in 1 2; do wait_text "$out/seed$s/learner.csv" "^[0-9]" 60 || fail "seed $s did not train within 60 s"; done
sleep 1
kill -TERM "$first"
wait "$first"
rc=$?
[ "$rc" = 130 ] || fail "seeds.py stopped by SIGTERM exited with $rc, not 130: $(tail -5 "$dir/first.log")"
for s in 1 2; do
  events "$out/seed$s" stop | tail -1 | grep -q '"reason":"interrupted"' ||
    fail "seed $s's last stop is not an interruption: $(events "$out/seed$s" stop)"
  [ -f "$out/seed$s/checkpoint/manifest.txtpb" ] || fail "seed $s left no checkpoint"
  running "farm-worker --id s${s}w1 --domain $((domain + s)) " && fail "a worker of seed $s still runs after seeds.py exited"
done
running "--run-dir $out/" && fail "a learner of seeds.py still runs after it exited"

# 2. The same command again refuses the existing runs rather than moving them aside.
if "${cmd[@]}" --seeds 1,2 > "$dir/again.log" 2>&1; then fail "seeds.py ran over existing runs without --resume"; fi
[ "$(events "$out/seed1" start | wc -l)" = 1 ] || fail "seed 1 was started again without --resume"

# 3. --resume with seed 3 added: seeds 1 and 2 go on from their checkpoints to their 10 s in all,
#    seed 3 runs from the start.
"${cmd[@]}" --seeds 1,2,3 --resume > "$dir/resume.log" 2>&1 || fail "seeds.py --resume failed: $(tail -5 "$dir/resume.log")"
for s in 1 2; do
  starts=$(events "$out/seed$s" start)
  [ "$(echo "$starts" | wc -l)" = 2 ] || fail "seed $s has not two starts: $starts"
  echo "$starts" | tail -1 | grep -q '"resumed":true' || fail "seed $s's second start is not a resume: $starts"
done
for s in 1 2 3; do
  stop=$(events "$out/seed$s" stop | tail -1)
  echo "$stop" | grep -q '"reason":"time limit' || fail "seed $s did not end on its time limit: $stop"
done
[ "$(events "$out/seed3" start | grep -c '"resumed":false')" = 1 ] || fail "seed 3 did not start once, fresh"
[ "$(wc -l < "$out/command.txt")" = 2 ] || fail "command.txt does not hold both commands: $(cat "$out/command.txt")"

# 4. --resume once all ended: nothing runs again.
"${cmd[@]}" --seeds 1,2,3 --resume > "$dir/done.log" 2>&1 || fail "seeds.py --resume of ended runs failed: $(tail -5 "$dir/done.log")"
for s in 1 2; do [ "$(events "$out/seed$s" start | wc -l)" = 2 ] || fail "seed $s, which had ended, was started again"; done
[ "$(events "$out/seed3" start | wc -l)" = 1 ] || fail "seed 3, which had ended, was started again"

farm_test_end "seeds.py stopped and resumed"
