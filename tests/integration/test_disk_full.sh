#!/usr/bin/env bash
# A full disk does not end a run: the learner's run directory on a small tmpfs, filled up after the
# first checkpoint. The next checkpoints fail, the last good one stays intact, training goes on
# (its updates read from farm-monitor: the run's own files are on the full disk); when space comes
# back the next checkpoint succeeds, the run ends normally with lost 0 and its summary event counts
# the failed checkpoints, and it resumes. A run whose checkpoint/ is gone but checkpoint.old/ is
# there resumes from that. Needs to mount a tmpfs (root); skipped (exit 77) where mounting is refused.
#   tests/integration/test_disk_full.sh LEARNER WORKER MONITOR
set -uo pipefail
learner=$(readlink -f "$1") worker=$(readlink -f "$2") monitor=$(readlink -f "$3")
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init disk-full 191
before_cleanup() { mountpoint -q "$dir/disk" && umount "$dir/disk"; }
mkdir -p "$dir/disk"
if ! mount -t tmpfs -o size=24m tmpfs "$dir/disk" 2>"$dir/mount.err"; then
  echo "SKIP: cannot mount a tmpfs for the full disk ($(cat "$dir/mount.err")); run as root"
  exit 77
fi
# The learner's updates as farm-monitor saw them last (its LearnerStats off the bus).
updates_now() { grep -o '"updates":[0-9]*' "$dir/monitor.jsonl" 2>/dev/null | tail -1 | grep -o "[0-9]*$"; }
# Checkpoints the learner wrote, from its events.
checkpoints_ok() { events "$run" checkpoint | grep -c '"ok":true'; }

cat >"$dir/cfg.txtpb" <<'CFG'
experiment_id: "it_disk_full"
task { name: "pendulum" }
sac { hidden: 64 hidden: 64 learning_starts: 500 buffer_size: 200000 publish_every_updates: 25 }
worker { envs_per_worker: 8 steps_per_batch: 25 max_batches_per_version: 4 }
eval { episodes: 2 every_seconds: 600 final_episodes: 2 }
checkpoint_every_seconds: 2
log_every_seconds: 1
stop { max_seconds: 30 }
CFG
run="$dir/disk/run"
"$learner" --config "$dir/cfg.txtpb" --run-dir "$run" --domain $domain >"$dir/learner.log" 2>&1 & lp=$!; pids+=($lp)
"$worker" --domain $domain --id dw >"$dir/worker.log" 2>&1 & pids+=($!)
"$monitor" --domain $domain --experiment it_disk_full --quiet --log "$dir/monitor.jsonl" >"$dir/monitor.out" 2>&1 &
pids+=($!)
for _ in $(seq 60); do [ "$(checkpoints_ok)" -ge 1 ] && break; sleep 1; done
[ "$(checkpoints_ok)" -ge 1 ] || fail "no first checkpoint: $(tail -5 "$dir/learner.log")"
good=$(grep -o "^updates: [0-9]*" "$run/checkpoint/manifest.txtpb")
# Fill the disk; three checkpoint periods on it.
dd if=/dev/zero of="$dir/disk/filler" bs=64k 2>/dev/null
ok_full=$(checkpoints_ok)
sleep 6
[ -f "$run/checkpoint/manifest.txtpb" ] || fail "the last good checkpoint is gone"
ls "$run" | grep -q "checkpoint.tmp" && fail "a half-written checkpoint folder was left on the full disk"
u1=$(updates_now); sleep 3; u2=$(updates_now)
[ -n "$u1" ] && [ -n "$u2" ] && [ "$u2" -gt "$u1" ] || fail "training stopped on the full disk (updates $u1 -> $u2)"
kill -0 $lp 2>/dev/null || fail "the learner died on the full disk"
# Space again: the next checkpoint succeeds.
rm -f "$dir/disk/filler"
sleep 5
[ "$(checkpoints_ok)" -gt "$ok_full" ] || fail "no checkpoint succeeded after space came back"
wait $lp; rc=$?
[ $rc = 0 ] || fail "learner exited $rc: $(tail -5 "$dir/learner.log")"
summary_batches_whole "$run" || fail "summary: $(events "$run" summary)"
fails=$(events "$run" summary | tail -1 | grep -o '"checkpoints_failed":[0-9]*' | grep -o "[0-9]*$")
[ "${fails:-0}" -ge 1 ] || fail "the summary event counts no failed checkpoint: $(events "$run" summary)"
echo "before the full disk: $good; $fails failed checkpoint(s) while full; now: $(grep -o "^updates: [0-9]*" "$run/checkpoint/manifest.txtpb")"

# Only checkpoint.old/ left (a crash between the two renames of a save): --resume takes it.
mv "$run/checkpoint" "$run/checkpoint.old"
sed -i 's/max_seconds: 30/max_seconds: 34/' "$dir/cfg.txtpb"
"$learner" --config "$dir/cfg.txtpb" --run-dir "$run" --domain $domain --resume >"$dir/learner-2.log" 2>&1 & lp=$!; pids+=($lp)
"$worker" --domain $domain --id dw2 >"$dir/worker-2.log" 2>&1 & pids+=($!)
wait $lp; rc=$?
[ $rc = 0 ] || fail "resumed learner exited $rc: $(tail -5 "$dir/learner-2.log")"
events "$run" start | tail -1 | grep -q '"resumed":true' || fail "did not resume: $(head -5 "$dir/learner-2.log")"

farm_test_end
