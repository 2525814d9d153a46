#!/usr/bin/env bash
# tools/seeds.py stopped by a signal (a batch system's time limit) loses nothing: the run in progress
# writes its checkpoint, no other seed starts, and `--resume` continues that run from its checkpoint
# and starts the seed that never ran; a run that ended on its own is kept as it is. Checked on the
# learners' events (start, stop), not on prose.
#   test_seeds_resume.sh SOURCE_DIR BUILD_DIR
set -uo pipefail
SRC=$1
BUILD=$2
source "$SRC/tests/integration/lib.sh"
farm_test_init seeds-resume 61
out=$dir/seeds

# The pendulum for 8 s of training, with a target it cannot reach (seeds.py judges the pendulum on it).
pendulum_config "$SRC" it_seeds 'target_eval_return: 1000 max_seconds: 8' "$dir/cfg.txtpb"
cmd=(python3 "$SRC/tools/seeds.py" "$dir/cfg.txtpb" --seeds 1,2 --workers 1 --parallel 1 --train-only
  --out "$out" --build "$BUILD" --domain "$domain")
seeds() { "${cmd[@]}" "$@"; }

# 1. Stopped while seed 1 trains: exit 130, seed 1 stopped with its checkpoint, seed 2 never begun.
"${cmd[@]}" > "$dir/first.log" 2>&1 &
pids+=($!)
first=$!
wait_text "$out/seed1/learner.csv" "^[0-9]" 60 || fail "seed 1 did not train within 60 s"
sleep 2
kill -TERM "$first"
wait "$first"
rc=$?
[ "$rc" = 130 ] || fail "seeds.py stopped by SIGTERM exited with $rc, not 130: $(tail -5 "$dir/first.log")"
events "$out/seed1" stop | tail -1 | grep -q '"reason":"interrupted"' ||
  fail "seed 1's last stop is not an interruption: $(events "$out/seed1" stop)"
[ -f "$out/seed1/checkpoint/manifest.txtpb" ] || fail "seed 1 left no checkpoint"
[ -e "$out/seed2" ] && fail "seed 2 started after the signal"
pgrep -f "run-dir $out/" > /dev/null && fail "a learner of seeds.py still runs after it exited"
pgrep -f "farm-worker --id s1w1 --domain $((domain + 1)) " > /dev/null && fail "a worker of seeds.py still runs after it exited"

# 2. The same command again refuses the existing run rather than moving it aside.
if seeds > "$dir/again.log" 2>&1; then fail "seeds.py ran over an existing run without --resume"; fi
[ "$(events "$out/seed1" start | wc -l)" = 1 ] || fail "seed 1 was started again without --resume"

# 3. --resume: seed 1 goes on from its checkpoint to its 8 s in all, seed 2 runs from the start.
seeds --resume > "$dir/resume.log" 2>&1 || fail "seeds.py --resume failed: $(tail -5 "$dir/resume.log")"
starts=$(events "$out/seed1" start)
[ "$(echo "$starts" | wc -l)" = 2 ] || fail "seed 1 has not two starts: $starts"
echo "$starts" | tail -1 | grep -q '"resumed":true' || fail "seed 1's second start is not a resume: $starts"
for s in 1 2; do
  stop=$(events "$out/seed$s" stop | tail -1)
  echo "$stop" | grep -q '"reason":"time limit' || fail "seed $s did not end on its time limit: $stop"
done
[ "$(events "$out/seed2" start | grep -c '"resumed":false')" = 1 ] || fail "seed 2 did not start once, fresh"
[ "$(wc -l < "$out/command.txt")" = 2 ] || fail "command.txt does not hold both commands: $(cat "$out/command.txt")"

# 4. --resume once all ended: nothing runs again.
seeds --resume > "$dir/done.log" 2>&1 || fail "seeds.py --resume of ended runs failed: $(tail -5 "$dir/done.log")"
[ "$(events "$out/seed1" start | wc -l)" = 2 ] || fail "seed 1, which had ended, was started again"
[ "$(events "$out/seed2" start | wc -l)" = 1 ] || fail "seed 2, which had ended, was started again"

farm_test_end "seeds.py stopped and resumed"
