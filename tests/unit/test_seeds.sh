#!/usr/bin/env bash
# tools/seeds.py --report-only on hand-made runs: the per-seed table (time to goal, kept best,
# final, final/best), the spread over seeds, the exit status, the errors, and measurements used again.
# usage: test_seeds.sh SOURCE_DIR
set -euo pipefail
SRC=$1
T=$(mktemp -d); trap 'rm -rf "$T"' EXIT
fail() { echo "FAIL: $*"; exit 1; }
seeds() { /usr/bin/python3 "$SRC/tools/seeds.py" "$@"; }

# A return task: seed 1 reaches -200 at 20 s and falls back to -450 (final/best 2.25 below 0.9 is
# flagged as -137 %); seed 2 reaches it at 30 s and holds; seed 3 never does.
cp "$SRC/deploy/configs/pendulum_sac.txtpb" "$T/pendulum.txtpb"
H=elapsed_s,env_steps,updates,mean_return,eval_return
mkdir -p "$T/p/seed1" "$T/p/seed2" "$T/p/seed3"
printf '%s\n10,1000,5,-900,-800\n20,2000,9,-500,-190\n25,2500,12,-400,nan\n30,3000,15,-300,-450\n' "$H" > "$T/p/seed1/learner.csv"
printf '%s\n10,1000,5,-900,-700\n30,3000,9,-300,-180\n40,4000,15,-200,-170\n' "$H" > "$T/p/seed2/learner.csv"
printf '%s\n10,1000,5,-900,-900\n50,5000,9,-800,-600\n' "$H" > "$T/p/seed3/learner.csv"
if out=$(seeds "$T/pendulum.txtpb" --report-only --out "$T/p" 2>&1); then fail "a seed missed the goal, exit 0"; fi
echo "$out"
grep -q "^| 1 | 30 | 3000 | 20 | -190 | -450 | -137 | yes | no |$" <<< "$out" || fail "seed 1 row"
grep -q "^| 2 | 40 | 4000 | 30 | -170 | -170 | +0 | yes | yes |$" <<< "$out" || fail "seed 2 row"
grep -q "^| 3 | 50 | 5000 | - | -600 | -600 | +0 | no | no |$" <<< "$out" || fail "seed 3 row"
grep -q "^- kept best: median -190, IQM -320 " <<< "$out" || fail "kept best spread"
grep -q "^- goal met by the kept best in 2 of 3 seeds, by the final policy in 1 of 3$" <<< "$out" || fail "goal count"
grep -q "^- final more than 10 % below kept best: seed 1$" <<< "$out" || fail "seed 1's drop not flagged"
grep -q "^- time to goal \[s\]: median 25, IQM 25 .* over 2 of 3 seeds$" <<< "$out" || fail "time to goal over the seeds that met it"
[ -s "$T/p/seeds.md" ] && [ -s "$T/p/seeds.csv" ] && [ -s "$T/p/seeds.png" ] || fail "seeds.md/csv/png not written"
[ "$(wc -l < "$T/p/seeds.csv")" = 4 ] || fail "seeds.csv: expected a header and 3 rows"

# A walking task: the crossing needs both conditions in one evaluation.
cp "$SRC/deploy/configs/a1_ppo.txtpb" "$T/a1.txtpb"
H=elapsed_s,env_steps,eval_return,eval_tracking_lin,eval_fell
mkdir -p "$T/w/seed1"
printf '%s\n10,1000,1,0.7,0.25\n20,2000,2,0.62,0.0\n30,3000,3,0.5,0.0\n' "$H" > "$T/w/seed1/learner.csv"
# The kept best walks (20 s), the final does not (0.5, 19 % below): exit 0, the drop flagged.
out=$(seeds "$T/a1.txtpb" --seeds 1 --report-only --out "$T/w" 2>&1) || fail "the kept best walks, exit non-zero: $out"
grep -q "^| 1 | 30 | 3000 | 20 | 0.62 | 0.5 | -19 | yes | no |$" <<< "$out" || fail "walking row: $out"
grep -q "^- final more than 10 % below kept best: seed 1$" <<< "$out" || fail "walking drop not flagged"

# A run that stops on its target between two learner.csv rows (SAC logs a row per interval): the
# evaluations, the final one included, come from the run's events (a line cut short is skipped).
mkdir -p "$T/s/seed4"
printf 'elapsed_s,env_steps,eval_return\n5.00,21000,nan\n10.02,42600,nan\n' > "$T/s/seed4/learner.csv"
cat > "$T/s/seed4/events.jsonl" <<'EV'
{"event":"evaluation","elapsed_s":6.3,"label":"eval","asked_elapsed_s":6.1,"episodes":10,"mean":-900.5}
{"event":"progress","elapsed_s":8.0,"env_steps":30000}
{"event":"evaluation","elapsed_s":10.1,"label":"eval","asked_elapsed_s":10.0,"episodes":10,"mean":-159.8}
{"event":"evaluation","elapsed_s":10.4,"label":"final","asked_elapsed_s":10.2,"episodes":50,"mean":-145.2}
{"event":"evaluation","elapsed_s":10.5,"label":"ev
EV
out=$(seeds "$T/pendulum.txtpb" --seeds 4 --report-only --out "$T/s" 2>&1) || fail "seed 4 met the goal, exit non-zero: $out"
grep -q "^| 4 | 10 | 42600 | 10 | -145 | -145 | +0 | yes | yes |$" <<< "$out" || fail "log and summary row: $out"

# A mobile robot's plot: the success of each evaluation from the run's events, the final one
# included (learner.csv has no success column), next to the goal; the points in seeds_curves.csv.
mkdir -p "$T/m/seed2"
printf 'elapsed_s,env_steps,eval_return\n60.0,1000,9.9\n' > "$T/m/seed2/learner.csv"
cat > "$T/m/seed2/events.jsonl" <<'EV'
{"event":"evaluation","label":"eval","asked_elapsed_s":60.0,"episodes":30,"mean":9.9,"metrics":{"success":0.967,"time_s":8.15}}
{"event":"evaluation","label":"eval","asked_elapsed_s":120.4,"episodes":30,"mean":2.1,"metrics":{"success":0.833,"time_s":9.7}}
{"event":"evaluation","label":"eval","asked_elapsed_s":200.0,"episodes":0,"given_up":true}
{"event":"evaluation","label":"final","asked_elapsed_s":415.9,"episodes":100,"mean":8.6,"metrics":{"success":0.94,"time_s":8.141}}
EV
(cd "$T/m" && /usr/bin/python3 -c "
import sys, types; sys.path.insert(0, '$SRC/tools'); import seeds
seeds.plot(types.SimpleNamespace(out='.', config='jetbot.txtpb'), 'mobile', float('nan'), [2])") \
  || fail "mobile plot"
[ -s "$T/m/seeds.png" ] || fail "mobile plot not written"
want="seed,elapsed_s,measure,value
2,60.0,success % (learner's evaluations),96.7
2,120.4,success % (learner's evaluations),83.3
2,415.9,success % (learner's evaluations),94.0"
[ "$(tr -d '\r' < "$T/m/seeds_curves.csv")" = "$want" ] || fail "mobile curve: $(cat "$T/m/seeds_curves.csv")"

# Errors name what is wrong.
err=$(seeds "$T/pendulum.txtpb" --seeds 1,x --report-only --out "$T/p" 2>&1) && fail "bad --seeds accepted"
grep -q "seeds: --seeds: expected a comma-separated list of integers, got '1,x'" <<< "$err" || fail "bad --seeds: $err"
grep -v '^seed:' "$T/pendulum.txtpb" > "$T/noseed.txtpb"
err=$(seeds "$T/noseed.txtpb" --report-only --out "$T/p" 2>&1) && fail "config without seed accepted"
grep -q "no top-level \`seed: N\` line" <<< "$err" || fail "no seed line: $err"
grep -v 'target_eval_return' "$T/pendulum.txtpb" > "$T/notarget.txtpb"
err=$(seeds "$T/notarget.txtpb" --report-only --out "$T/p" 2>&1) && fail "return task without target accepted"
grep -q "stop.target_eval_return, which the config does not set" <<< "$err" || fail "no target: $err"
# The mCLARI microbot: each policy's farm-mclari-eval table, made by the same command after the
# policy was written, is used again (no program to run here: --build names none); the plot draws the
# worst terrain's share that the learner logged for each evaluation. A policy written after its
# table is measured again, and a measurement that cannot run leaves the old table in place.
cp "$SRC/deploy/configs/mclari_sac_terrain.txtpb" "$T/mcl.txtpb"
# Older than the tables below: a file's time has the clock's coarse tick, so a table written within
# the tick of this copy would not be "after what it names" and would be measured again.
touch -d '3 hours ago' "$T/mcl.txtpb"
R="$T/c/seed1"; mkdir -p "$R/best" "$R/checkpoint"
printf 'elapsed_s,env_steps,eval_return\n1500,80000,100\n' > "$R/learner.csv"
touch -d '2 hours ago' "$R/best" "$R/checkpoint"
table() {  # WHICH DIR ROUGH_DRY_PERCENT
  echo "\$ $T/nobuild/tools/farm-mclari-eval --config $T/mcl.txtpb --checkpoint $R/$2 --best $SRC/docs/data/mclari_best_180s.csv --episodes 10"
  for t in plain-normal plain-wet plain-dry rough-normal rough-wet; do
    echo "| $t | 10 | 0.2623 | 0 / 10 | 0 / 10 | 150.0 | (pi/2, 0, pi), 150 Hz | 0.2624 | 100 % |"; done
  echo "| rough-dry | 10 | 0.1472 | 0 / 10 | 0 / 10 | 1.0 | (pi/2, 0, pi), 1 Hz | 0.1573 | $3 % |"
}
table best best 94 > "$R/eval_best.txt"; table final checkpoint 46 > "$R/eval_final.txt"
cat > "$R/events.jsonl" <<'EV'
{"event":"evaluation","label":"eval","asked_elapsed_s":150.0,"episodes":10,"mean":1.0,"metrics_min":{"share":0.4123},"confirmed":true}
{"event":"evaluation","label":"eval","asked_elapsed_s":225.0,"episodes":10,"mean":1.0,"metrics_min":{"share":0.99},"confirmed":false}
{"event":"evaluation","label":"eval","asked_elapsed_s":300.0,"episodes":10,"mean":1.0,"metrics_min":{"share":0.9512},"confirmed":true}
EV
mseeds() { seeds "$T/mcl.txtpb" --seeds 1 --report-only --out "$T/c" --build "$T/nobuild" "$@"; }
out=$(mseeds 2>&1) || fail "the kept best meets the goal, exit non-zero: $out"
grep -q "^| 1 | 1500 | 80000 | - | 94 | 46 | -51 | yes | no |$" <<< "$out" || fail "mclari row: $out"
[ "$(grep -c "measured already by the same command" <<< "$out")" = 2 ] || fail "the tables were not used again: $out"
grep -q "Trained with: \`not recorded (no command.txt)\`; measured with: \`tools/seeds.py $T/mcl.txtpb" <<< "$out" \
  || fail "the commands: $out"
want="seed,elapsed_s,measure,value
1,150.0,worst terrain % of the best fixed point (learner's evaluations),41.23
1,300.0,worst terrain % of the best fixed point (learner's evaluations),95.12"
[ "$(tr -d '\r' < "$T/c/seeds_curves.csv")" = "$want" ] || fail "mclari curve: $(cat "$T/c/seeds_curves.csv")"
# The plot's labels stay inside the figure (the worst-terrain label is long).
(cd "$T/c" && /usr/bin/python3 -c "
import sys, types; sys.path.insert(0, '$SRC/tools'); import seeds
fig = seeds.plot(types.SimpleNamespace(out='.', config='mcl.txtpb'), 'mclari', float('nan'), [1])
r = fig.canvas.get_renderer(); box = fig.bbox
for a in (fig.axes[0].yaxis.label, fig.axes[0].xaxis.label, fig.axes[0].title):
    e = a.get_window_extent(r)
    assert e.x0 >= 0 and e.y0 >= 0 and e.x1 <= box.x1 and e.y1 <= box.y1, (a.get_text(), e, box)") \
  || fail "mclari plot: a label is cut off"
echo "tools/seeds.py $T/mcl.txtpb --seeds 1 --workers 7" > "$T/c/command.txt"
touch "$R/best/manifest.txtpb"
out=$(mseeds 2>&1) && fail "the kept best could not be measured, exit 0: $out"
grep -q "Trained with: \`tools/seeds.py $T/mcl.txtpb --seeds 1 --workers 7\`" <<< "$out" || fail "training command: $out"
grep -q "^| 1 | 1500 | 80000 | - | - | 46 | - | no | no |$" <<< "$out" || fail "mclari row, best not measured: $out"
grep -q "seeds: cannot run $T/nobuild/tools/farm-mclari-eval: No such file or directory" <<< "$out" || fail "missing program: $out"
grep -q "| rough-dry .* | 94 % |$" "$R/eval_best.txt" || fail "the old table was lost: $(cat "$R/eval_best.txt")"

# A run whose last evaluation was its best: RUN/best holds the final policy itself (same version,
# same weights; the manifests differ in their counts), so its table is the final's too, with no
# second measurement (none could run here). Weights that differ by a byte are measured apart.
S="$T/s/seed1"; mkdir -p "$S/best/sac" "$S/checkpoint/sac" "$T/s/logs"
printf 'elapsed_s,env_steps,eval_return\n1500,80000,100\n' > "$S/learner.csv"
printf 'policy_version: 42\nbatches_ok: 10\n' > "$S/best/manifest.txtpb"
printf 'policy_version: 42\nbatches_ok: 12\n' > "$S/checkpoint/manifest.txtpb"
printf 'weights' > "$S/best/sac/sac.pt"; cp "$S/best/sac/sac.pt" "$S/checkpoint/sac/sac.pt"
touch -d '2 hours ago' "$S/best" "$S/checkpoint" "$S/best/manifest.txtpb" "$S/best/sac/sac.pt" \
  "$S/checkpoint/manifest.txtpb" "$S/checkpoint/sac/sac.pt"
R="$S" table best best 94 > "$S/eval_best.txt"
sseeds() { seeds "$T/mcl.txtpb" --seeds 1 --report-only --out "$T/s" --build "$T/nobuild" "$@"; }
out=$(sseeds 2>&1) || fail "same policy: exit non-zero: $out"
grep -q "^| 1 | 1500 | 80000 | - | 94 | 94 | +0 | yes | yes |$" <<< "$out" || fail "same policy row: $out"
grep -q "seeds: seed 1: the final policy is the kept best (policy v42, the same files): measured once" <<< "$out" \
  || fail "same policy note: $out"
grep -q "^- final policy is the kept best, measured once: seed 1 (v42)$" <<< "$out" || fail "same policy line: $out"
grep -q "cannot run" <<< "$out" && fail "same policy measured twice: $out"
printf 'weightz' > "$S/checkpoint/sac/sac.pt"; touch -d '2 hours ago' "$S/checkpoint/sac/sac.pt"
out=$(sseeds 2>&1) || fail "other final: exit non-zero: $out"
grep -q "^| 1 | 1500 | 80000 | - | 94 | - | - | yes | no |$" <<< "$out" || fail "other final row: $out"
grep -q "^- final policy is the kept best, measured once: none$" <<< "$out" || fail "other final line: $out"

# A mobile robot's two measurements name the same run folder, which holds both: each is used again
# (the other's table, written later, is not taken for a newer policy).
cp "$SRC/deploy/configs/kaya_sac.txtpb" "$T/kaya.txtpb"
K="$T/k/seed1"; mkdir -p "$K/best" "$K/checkpoint"
printf 'elapsed_s,env_steps,eval_return\n60,90000,9.5\n' > "$K/learner.csv"
# Time to goal: the first of the learner's evaluations at 95 % success or more (the final one aside).
cat > "$K/events.jsonl" <<'EV'
{"event":"evaluation","label":"eval","asked_elapsed_s":20.0,"episodes":30,"mean":5.1,"metrics":{"success":0.9}}
{"event":"evaluation","label":"eval","asked_elapsed_s":40.0,"episodes":30,"mean":9.9,"metrics":{"success":0.967}}
{"event":"evaluation","label":"final","asked_elapsed_s":60.0,"episodes":100,"mean":9.5,"metrics":{"success":0.96}}
EV
touch -d '2 hours ago' "$K/best" "$K/checkpoint" "$K/learner.csv" "$K/events.jsonl" "$K"
printf '$ %s\nsuccess rate   96.0 %%\n' "$T/nobuild/tools/farm-mobile-eval --run-dir $K --episodes 100 --best" > "$K/eval_best.txt"
printf '$ %s\nsuccess rate   97.0 %%\n' "$T/nobuild/tools/farm-mobile-eval --run-dir $K --episodes 100" > "$K/eval_final.txt"
touch -d '1 hour ago' "$K/eval_best.txt" "$K"
out=$(seeds "$T/kaya.txtpb" --seeds 1 --report-only --out "$T/k" --build "$T/nobuild" 2>&1) || fail "mobile: exit non-zero: $out"
grep -q "^| 1 | 60 | 90000 | 40 | 96 | 97 | +1 | yes | yes |$" <<< "$out" || fail "mobile row: $out"
[ "$(grep -c "measured already by the same command" <<< "$out")" = 2 ] || fail "mobile tables not used again: $out"

# A seed without a run folder (a signal stopped training before it started) is reported as
# missing beside the others, not measured: the report is written and the exit status is 1.
rc=0; out=$(seeds "$T/kaya.txtpb" --seeds 1,3 --report-only --out "$T/k" --build "$T/nobuild" 2>&1) || rc=$?
[ $rc = 1 ] || fail "a missing seed: exit $rc, expected 1: $out"
[ "$(tr -d '\r' < "$T/k/seeds.csv" | tail -1)" = "3,nan,nan,nan,nan,nan,nan,0,0" ] \
  || fail "missing seed: seeds.csv $(cat "$T/k/seeds.csv")"

# A return task's run that stopped on its target before learner.csv's first row, and one that ended
# before its first periodic evaluation: their evaluations come from the events alone.
mkdir -p "$T/e/seed1" "$T/e/seed2"
printf 'elapsed_s,env_steps,eval_return\n' > "$T/e/seed1/learner.csv"
cat > "$T/e/seed1/events.jsonl" <<'EV'
{"event":"evaluation","label":"eval","asked_elapsed_s":3.0,"episodes":10,"mean":-159.8}
{"event":"evaluation","label":"final","asked_elapsed_s":4.1,"episodes":50,"mean":-145.2}
{"event":"summary","wall_s":4.2,"env_steps":21000}
EV
printf 'elapsed_s,env_steps,eval_return\n5,25000,nan\n7,25000,nan\n' > "$T/e/seed2/learner.csv"
echo '{"event":"evaluation","label":"final","asked_elapsed_s":7.0,"episodes":50,"mean":-145.2}' > "$T/e/seed2/events.jsonl"
out=$(seeds "$T/pendulum.txtpb" --seeds 1,2 --report-only --out "$T/e" 2>&1) || fail "events alone: exit non-zero: $out"
want="seed,wall_s,env_steps,goal_time_s,best,final,final_minus_best_pct,best_ok,final_ok
1,4.2,21000.0,3.0,-145.2,-145.2,0.0,1,1
2,7.0,25000.0,nan,-145.2,-145.2,0.0,1,1"
[ "$(tr -d '\r' < "$T/e/seeds.csv")" = "$want" ] || fail "events alone: seeds.csv $(cat "$T/e/seeds.csv")"

# Training whose learner fails exits 1 (a batch script must not go on to measure).
mkdir -p "$T/fb/learner" "$T/fb/worker"
printf '#!/bin/sh\necho "cannot open the config" >&2\nexit 1\n' > "$T/fb/learner/farm-learner"
printf '#!/bin/sh\nexit 0\n' > "$T/fb/worker/farm-worker"
chmod +x "$T/fb/learner/farm-learner" "$T/fb/worker/farm-worker"
rc=0; out=$(seeds "$T/pendulum.txtpb" --seeds 1,2 --train-only --out "$T/f" --build "$T/fb" 2>&1) || rc=$?
[ $rc = 1 ] || fail "every learner failed, --train-only: exit $rc, expected 1: $out"

echo "seeds.py report: ok"
