#!/usr/bin/env bash
# farm-play on the pendulum quickstart's run, headless (OSMesa, no GPU, no display):
#   tests/integration/test_play.sh LEARNER WORKER PLAY SOURCE_DIR
# 1. A learner and a worker (real DDS) train deploy/configs/pendulum_sac.txtpb for a few seconds.
# 2. farm-play writes its checkpoint's policy to an MP4 that ffprobe decodes with the frame count
#    the episodes' simulated time gives at the video's rate (and that its record says), H.264 in
#    yuv420p at the asked size; two frames, compared outside the text overlay, differ (the rod moves).
# 3. RUN/best to an animated GIF that ffprobe reads; --view-check finds the rod in every frame and
#    every row of the overlay within its column.
# 4. Clear errors: a run folder without a policy, a run folder passed as a checkpoint, an unknown
#    task in a checkpoint's config, ffmpeg missing, an unwritable output, an unknown output kind.
# What farm-play did is read from its --events record (its kinds: tools/play.cpp).
set -uo pipefail
learner=$(readlink -f "$1") worker=$(readlink -f "$2") play=$(readlink -f "$3") src=$(readlink -f "$4")
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init play 131
command -v ffprobe >/dev/null || { echo "ffprobe missing (Debian's ffmpeg, deploy/install-deps.sh)"; exit 1; }

# 1. The quickstart's experiment, stopped on time after a few seconds and evaluated briefly.
sed -e 's/max_seconds: 480/max_seconds: 8/' -e 's/every_seconds: 10/every_seconds: 3/' \
    -e 's/final_episodes: 50/final_episodes: 2/' -e 's/episodes: 10/episodes: 2/' \
    "$src/deploy/configs/pendulum_sac.txtpb" >"$dir/cfg.txtpb"
grep -q "max_seconds: 8" "$dir/cfg.txtpb" || fail "could not shorten the quickstart's config"
"$learner" --config "$dir/cfg.txtpb" --run-dir "$dir/run" --domain $domain >"$dir/learner.log" 2>&1 & lp=$!
pids+=($lp)
"$worker" --domain $domain --id play1 >"$dir/worker.log" 2>&1 & pids+=($!)
wait $lp || fail "learner exited $?: $(tail -5 "$dir/learner.log")"
[ -d "$dir/run/checkpoint/sac" ] && [ -d "$dir/run/best/sac" ] || { failed=1; farm_test_end; }

# 2. MP4: 2 episodes of 40 steps of 0.05 s (Pendulum-v1's dt) at 20 fps: 2 s each, 41 frames each
# (the reset's and one per 0.05 s).
"$play" --run "$dir/run" --out "$dir/p.mp4" --episodes 2 --max-steps 40 --width 320 --height 240 --fps 20 \
    --seed 3 --events "$dir/play.jsonl" >"$dir/play.out" 2>"$dir/play.err" ||
  fail "farm-play to MP4 exited $?: $(cat "$dir/play.err")"
cat "$dir/play.out"
python3 -c '
import json, sys
ep = [e for e in map(json.loads, open(sys.argv[1])) if e["event"] == "episode"]
ok = [e for e in ep if e["of"] == 2 and e["return"] < 0 and e["steps"] == 40 and e["cut_short"]
      and abs(e["seconds"] - 2.0) < 0.005 and e["frames"] == 41 and "upright_fraction" in e["metrics"]]
sys.exit(not (len(ep) == 2 and [e["index"] for e in ok] == [1, 2]))
' "$dir/play.jsonl" || fail "not two 41-frame episodes of 40 steps cut short at 2 s: $(cat "$dir/play.jsonl")"
has_event "$dir/play.jsonl" wrote path="\"$dir/p.mp4\"" frames=82 width=320 height=240 fps=20 ||
  fail "no 82-frame video written: $(cat "$dir/play.jsonl")"
probe=$(ffprobe -v error -count_frames -select_streams v:0 \
    -show_entries stream=codec_name,pix_fmt,width,height,nb_read_frames -of default=nw=1 "$dir/p.mp4")
echo "$probe"
for want in codec_name=h264 pix_fmt=yuv420p width=320 height=240 nb_read_frames=82; do
  grep -qx "$want" <<<"$probe" || fail "ffprobe: expected $want"
done
# Frames 0 and 30 (1.5 s apart, same episode), the right half only (the overlay is at the top left).
for n in 0 30; do
  ffmpeg -v error -i "$dir/p.mp4" -vf "select=eq(n\,$n),crop=iw/2:ih:iw/2:0" -frames:v 1 -f rawvideo \
      -pix_fmt gray "$dir/f$n.raw" || fail "could not extract frame $n"
done
python3 - "$dir/f0.raw" "$dir/f30.raw" <<'PY' || fail "frames 0 and 30 do not differ"
import sys
a, b = (open(p, "rb").read() for p in sys.argv[1:])
assert len(a) == len(b) == 160 * 240, (len(a), len(b))
changed = sum(abs(x - y) > 16 for x, y in zip(a, b))
print("frames 0 and 30: %d of %d pixels of the right half changed" % (changed, len(a)))
assert changed > 100, changed
PY
# The same seed gives the same episodes (the policy is deterministic): the same returns.
"$play" --run "$dir/run" --out "$dir/again.mp4" --episodes 2 --max-steps 40 --width 320 --height 240 --fps 20 \
    --seed 3 --events "$dir/again.jsonl" >/dev/null 2>&1 || fail "second farm-play exited $?"
events_same_but_time "$dir/play.jsonl" "$dir/again.jsonl" episode || fail "same seed, other episodes"

# 3. GIF from RUN/best, with the robot in view of every frame.
"$play" --run "$dir/run" --best --out "$dir/p.gif" --max-steps 20 --width 320 --height 240 --fps 10 --view-check \
    --events "$dir/gif.jsonl" >"$dir/gif.out" 2>"$dir/gif.err" ||
  fail "farm-play to GIF exited $?: $(cat "$dir/gif.err")"
cat "$dir/gif.out"
has_event "$dir/gif.jsonl" view root_body='"rod"' lost_frame=null cut_frame=null ||
  fail "no view check of the rod: $(cat "$dir/gif.jsonl")"
probe=$(ffprobe -v error -count_frames -select_streams v:0 -show_entries stream=codec_name,width,height,nb_read_frames \
    -of default=nw=1 "$dir/p.gif")
echo "$probe"
for want in codec_name=gif width=320 height=240; do grep -qx "$want" <<<"$probe" || fail "GIF: expected $want"; done
frames=$(sed -n 's/^nb_read_frames=//p' <<<"$probe")
[ "${frames:-0}" -gt 1 ] || fail "GIF: $frames frames"

# 4. Errors, each with exit 2 and the message that names what was wrong.
expect_error() {  # WHAT PATTERN ARGS...
  local what=$1 pattern=$2
  shift 2
  out=$("$@" 2>&1 >/dev/null); rc=$?
  [ $rc = 2 ] && grep -q -- "$pattern" <<<"$out" || fail "$what: rc $rc, '$out'"
}
mkdir -p "$dir/empty"
expect_error "run without a policy" "run folder $dir/empty holds no policy: $dir/empty/checkpoint/manifest.txtpb does not exist" \
    "$play" --run "$dir/empty" --out "$dir/x.mp4"
expect_error "run folder as a checkpoint" "it is a run folder: pass its checkpoint/ or best/" \
    "$play" --checkpoint "$dir/run" --out "$dir/x.mp4"
cp -r "$dir/run/checkpoint" "$dir/walker"
sed -i 's/name: \\"pendulum\\"/name: \\"walker\\"/' "$dir/walker/manifest.txtpb"
grep -q 'walker' "$dir/walker/manifest.txtpb" || fail "could not rename the task in the manifest"
expect_error "unknown task" "walker" "$play" --checkpoint "$dir/walker" --out "$dir/x.mp4"
expect_error "ffmpeg missing" "ffmpeg not found: no executable 'ffmpeg' on PATH" \
    env PATH=/nonexistent "$play" --run "$dir/run" --out "$dir/x.mp4"
expect_error "ffmpeg named wrongly" "ffmpeg program $dir/nothing is not an executable file" \
    "$play" --run "$dir/run" --out "$dir/x.mp4" --ffmpeg "$dir/nothing"
touch "$dir/file"
expect_error "unwritable output" "cannot write --out $dir/file/x.mp4" "$play" --run "$dir/run" --out "$dir/file/x.mp4"
expect_error "unknown output kind" "the extension '.avi'" "$play" --run "$dir/run" --out "$dir/x.avi"
expect_error "odd MP4 size" "an even width and height" "$play" --run "$dir/run" --out "$dir/x.mp4" --width 321
expect_error "bad number" "--fps: Value 2x not in range 1 to 240" "$play" --run "$dir/run" --out "$dir/x.mp4" --fps 2x
[ -e "$dir/x.mp4" ] && [ -s "$dir/x.mp4" ] && fail "a failed run left $dir/x.mp4 behind"

farm_test_end "farm-play: MP4 and GIF of the quickstart's run, errors named"
