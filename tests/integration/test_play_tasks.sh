#!/usr/bin/env bash
# farm-play on every registered task, untrained (the shipped experiment's initial networks, from
# --config): half a simulated second of each (the microbot: its first 1 s step) to an MP4 that
# ffprobe reads with the frame count of farm-play's --events record ("wrote"), with the robot in
# the picture of every frame and every row of the overlay within its column at the README clips'
# 640 x 360 (--view-check: the robot's bodies cover at least 20 pixels of each; no row wider than
# its column).
# Every task of the registry (robots/tasks.def) must have a shipped experiment in deploy/configs/.
#   tests/integration/test_play_tasks.sh PLAY SOURCE_DIR
set -uo pipefail
play=$(readlink -f "$1") src=$(readlink -f "$2")
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init play-tasks 0

tasks=$(sed -n 's/^TASK(\([a-z_0-9]*\), .*/\1/p' "$src/robots/tasks.def")
[ "$(wc -w <<<"$tasks")" -ge 8 ] || fail "could not read the task registry: '$tasks'"
for task in $tasks; do
  cfg=$(grep -l "^  name: \"$task\"" "$src"/deploy/configs/*.txtpb | head -1)
  [ -n "$cfg" ] || { fail "no shipped experiment for task $task"; continue; }
  if ! "$play" --config "$cfg" --out "$dir/$task.mp4" --max-seconds 0.5 --width 640 --height 360 --fps 10 \
      --view-check --events "$dir/$task.jsonl" >"$dir/$task.out" 2>"$dir/$task.err"; then
    fail "$task ($(basename "$cfg")): $(cat "$dir/$task.err" "$dir/$task.out")"
    continue
  fi
  echo "$task ($(basename "$cfg")): $(grep '^view:' "$dir/$task.out")"
  frames=$(ffprobe -v error -count_frames -select_streams v:0 -show_entries stream=nb_read_frames -of csv=p=0 \
      "$dir/$task.mp4")
  printed=$(event_of "$dir/$task.jsonl" wrote 'e["frames"]')
  [ -n "$printed" ] && [ "$frames" = "$printed" ] && [ "$frames" -ge 6 ] ||
    fail "$task: ffprobe reads $frames frames, farm-play wrote '$printed'"
done
farm_test_end "farm-play on every registered task"
