#!/usr/bin/env bash
# tests/bench/bench_seeds.sh REPORT_ONLY=1: its table from runs already made (bench_workers.sh
# rows and the learners' events): each ratio, the count within the bound (a run that missed the goal
# is not), the medians over the seeds that reached the goal, each run's evaluations, the updates at
# each run's goal evaluation, and the errors.
# usage: test_bench_seeds.sh SOURCE_DIR
set -euo pipefail
SRC=$1
T=$(mktemp -d); trap 'rm -rf "$T"' EXIT
fail() { echo "FAIL: $*"; exit 1; }
cp "$SRC/deploy/configs/kaya_sac.txtpb" "$T/kaya.txtpb"
row() {  # SEED COUNT TIME UPDATES_PER_S UTD: one bench_workers.sh row (its format)
  printf '%8d %14s %10s %12s %10s %10s %8s %9s %9s  %s\n' "$2" "$3" 40.0 200000 50000 "$4" "$5" 0/0 0/0 \
    "evaluation goal reached" >>"$T/out/seed$1.txt"
}
mkdir -p "$T/out"
for s in 1 2 3 4; do
  printf '%8s %14s\n' workers "time to goal" >"$T/out/seed$s.txt"
done
row 1 2 35.1 1131 0.2477; row 1 15 5.0 2460 0.0815
row 2 2 25.0 1228 0.2463; row 2 15 12.5 2561 0.0860   # exactly half: within
row 3 2 30.0 1090 0.2471; row 3 15 25.1 2784 0.0949
row 4 2 40.1 1372 0.2482; row 4 15 - 2577 0.0613       # stopped on a limit
# The learners' evaluation events (learner/events.h): an evaluation given up (no answer) and other
# kinds are not evaluations; the final one is not a training evaluation.
mkdir -p "$T/out/seed1/w2/learner"
cat >"$T/out/seed1/w2/learner/events.jsonl" <<'EV'
{"event":"evaluation","elapsed_s":5.9,"label":"eval","policy_version":38,"updates":1200,"asked_elapsed_s":5.0,"episodes":30,"mean":9.7,"min":1.0,"max":12.0,"metrics":{"success":0.0,"time_s":8.1},"confirmed":true}
{"event":"progress","elapsed_s":10.0,"updates":3008,"eval_return":9.7}
{"event":"evaluation","elapsed_s":30.2,"label":"eval","policy_version":700,"episodes":0,"given_up":true}
{"event":"evaluation","elapsed_s":35.8,"label":"eval","policy_version":829,"updates":26304,"asked_elapsed_s":35.1,"episodes":30,"mean":13.0,"min":11.0,"max":14.0,"metrics":{"success":0.9666666666666667,"time_s":6.7},"confirmed":true}
EV
mkdir -p "$T/out/seed1/w15/learner"
cat >"$T/out/seed1/w15/learner/events.jsonl" <<'EV'
{"event":"evaluation","elapsed_s":3.1,"label":"eval","policy_version":20,"updates":1500,"asked_elapsed_s":2.5,"episodes":30,"mean":2.0,"min":0.0,"max":4.0,"metrics":{"success":0.5,"time_s":9.0},"confirmed":true}
{"event":"evaluation","elapsed_s":5.6,"label":"eval","policy_version":430,"updates":13864,"asked_elapsed_s":5.0,"episodes":30,"mean":12.0,"min":10.0,"max":13.0,"metrics":{"success":0.9666666666666667,"time_s":6.0},"confirmed":true}
{"event":"evaluation","elapsed_s":7.0,"label":"final","policy_version":431,"updates":14100,"asked_elapsed_s":6.1,"episodes":100,"mean":12.5,"min":10.0,"max":13.0,"metrics":{"success":0.98,"time_s":6.0},"confirmed":true}
EV
bs() { REPORT_ONLY=1 bash "$SRC/tests/bench/bench_seeds.sh" /nonexistent/learner /nonexistent/worker "$@"; }
out=$(bs "$T/kaya.txtpb" "1 2 3 4" "2 15" "$T/out" 2>&1) || fail "report: exit non-zero: $out"
echo "$out"
grep -qF "| 1 | 35.1 s, 1131 upd/s, UTD 0.2477 | 5.0 s, 2460 upd/s, UTD 0.0815 | 0.14 |" <<<"$out" || fail "seed 1 row"
grep -qF "| 2 | 25.0 s, 1228 upd/s, UTD 0.2463 | 12.5 s, 2561 upd/s, UTD 0.0860 | 0.50 |" <<<"$out" || fail "seed 2 row"
grep -qF "| 3 | 30.0 s, 1090 upd/s, UTD 0.2471 | 25.1 s, 2784 upd/s, UTD 0.0949 | 0.84 |" <<<"$out" || fail "seed 3 row"
grep -qF "| 4 | 40.1 s, 1372 upd/s, UTD 0.2482 | - s, 2577 upd/s, UTD 0.0613 | - |" <<<"$out" || fail "seed 4 row"
# Medians: 2 workers over four seeds (30.0 and 35.1), 15 workers over the three that reached the
# goal, the ratio over those three (0.14, 0.50, 0.84).
grep -qF "| median | 32.5 s | 12.5 s | 0.50 |" <<<"$out" || fail "median row"
grep -qF "15 workers within 0.5 of 2 workers' time: 2 of 4 seeds" <<<"$out" || fail "count within"
# The sign test: 2 or more of 4 within has probability 11/16 where a seed is within with 1/2.
grep -qxF "15 workers: median ratio to 2 workers at most 0.5 by a sign test over 4 seeds: 2 within, p = 0.6875" \
  <<<"$out" || fail "sign test"
grep -qF "evaluations (success at the time asked):" <<<"$out" || fail "evaluations header"
grep -qxF "seed 1, 2 workers: 0.000@5.0 0.967@35.1" <<<"$out" || fail "seed 1 evaluations"
grep -qxF "seed 2, 15 workers: none" <<<"$out" || fail "a run without events"
grep -qxF "seed 1, 15 workers: 0.500@2.5 0.967@5.0" <<<"$out" || fail "seed 1 evaluations, 15 workers"
# The updates at the goal's evaluation (the one asked at the time to goal, not the final one), per
# count in the seeds' order: "-" where a run has no events or missed the goal (seed 4, 15 workers).
grep -qF "updates when the goal's evaluation was asked:" <<<"$out" || fail "updates header"
grep -qxF "2 workers: 26304 - - - (median 26304)" <<<"$out" || fail "updates at the goal, 2 workers"
grep -qxF "15 workers: 13864 - - - (median 13864)" <<<"$out" || fail "updates at the goal, 15 workers"
# A tighter bound counts fewer seeds.
out=$(RATIO_AT_MOST=0.2 bs "$T/kaya.txtpb" "1 2 3 4" "2 15" "$T/out" 2>&1) || fail "bound: $out"
grep -qF "15 workers within 0.2 of 2 workers' time: 1 of 4 seeds" <<<"$out" || fail "RATIO_AT_MOST 0.2: $out"
grep -qF "at most 0.2 by a sign test over 4 seeds: 1 within, p = 0.9375" <<<"$out" || fail "sign test, 0.2: $out"
# A stop without a metric: the evaluations' mean return.
out=$(STOP='target_eval_return: 12 max_seconds: 60' bs "$T/kaya.txtpb" "1 2 3 4" "2 15" "$T/out" 2>&1) || fail "mean return: $out"
grep -qxF "seed 1, 2 workers: 9.7@5.0 13.0@35.1" <<<"$out" || fail "mean return evaluations: $out"
# GOAL_RETURN: from each run's events, the time its evaluations first reached the goal and whether
# the final and every evaluation from then on stayed within KEEP_WITHIN of the kept best.
ev() {  # DIR LABEL MEAN ASKED_S CONFIRMED
  printf '{"event":"evaluation","label":"%s","mean":%s,"asked_elapsed_s":%s,"elapsed_s":%s,"confirmed":%s}\n' \
    "$2" "$3" "$4" "$4" "$5" >>"$1/learner/events.jsonl"
}
for r in seed1/w2 seed1/w15; do rm -f "$T/out/$r/learner/events.jsonl"; done
ev "$T/out/seed1/w2" eval 8 10 true; ev "$T/out/seed1/w2" eval 12.5 20 true; ev "$T/out/seed1/w2" eval 3 25 false
ev "$T/out/seed1/w2" eval 11.5 30 true; ev "$T/out/seed1/w2" final 12.0 40 true
echo '{"event":"best","score":12.5}' >>"$T/out/seed1/w2/learner/events.jsonl"
ev "$T/out/seed1/w15" eval 12.0 5 true; ev "$T/out/seed1/w15" eval 10.0 10 true; ev "$T/out/seed1/w15" final 12.2 12 true
out=$(GOAL_RETURN=12 bs "$T/kaya.txtpb" "1" "2 15" "$T/out" 2>&1) || fail "GOAL_RETURN: $out"
grep -qxF "| seed 1, 2 workers | 20.0 s | 12.5 | 12.0 (0.96) | 11.5 (0.92) | kept |" <<<"$out" || fail "kept run: $out"
grep -qxF "| seed 1, 15 workers | 5.0 s | 12.2 | 12.2 (1.00) | 10.0 (0.82) | not kept: below 11.0 |" <<<"$out" ||
  fail "a run that lost more than a tenth after the goal: $out"
grep -qxF "2 of 2 runs reached 12; 1 kept it" <<<"$out" || fail "keep count: $out"
out=$(GOAL_RETURN=12 KEEP_WITHIN=0.2 bs "$T/kaya.txtpb" "1" "2 15" "$T/out" 2>&1) || fail "KEEP_WITHIN: $out"
grep -qxF "2 of 2 runs reached 12; 2 kept it" <<<"$out" || fail "KEEP_WITHIN 0.2: $out"
# Errors name what is wrong and exit 2.
set +e
err=$(bs "$T/kaya.txtpb" "1 5" "2 15" "$T/out" 2>&1); rc=$?
set -e
[ $rc = 2 ] && grep -qF "no run of seed 5 in $T/out" <<<"$err" || fail "missing seed: rc $rc: $err"
set +e
err=$(bs "$T/kaya.txtpb" "1 x" "2 15" "$T/out" 2>&1); rc=$?
set -e
[ $rc = 2 ] && grep -qF "seed 'x' is not a whole number" <<<"$err" || fail "bad seed: rc $rc: $err"
# CONFIG_ONLY=1 writes each seed's config and runs nothing: SET_LINES replaces a field SET_BLOCK
# already sets (jetbot_dqn_gpu's eval sets episodes: 400) and leaves the block's other fields.
cp "$SRC/deploy/configs/jetbot_dqn_gpu.txtpb" "$T/jetbot.txtpb"
grep -qE '^  episodes: [0-9]+$' "$T/jetbot.txtpb" || fail "jetbot_dqn_gpu.txtpb's eval sets no episodes: the case below tests nothing"
out=$(SET_BLOCK=eval SET_LINES='episodes: 60' CONFIG_ONLY=1 bash "$SRC/tests/bench/bench_seeds.sh" /nonexistent/learner \
  /nonexistent/worker "$T/jetbot.txtpb" "7" "1 15" "$T/cfg" 2>&1) || fail "CONFIG_ONLY: $out"
c=$T/cfg/seed7.txtpb
[ -r "$c" ] || fail "CONFIG_ONLY wrote no $c: $out"
[ ! -e "$T/cfg/seed7.txt" ] || fail "CONFIG_ONLY ran something"
eval_block=$(sed -n '/^eval {/,/^}/p' "$c")
[ "$(grep -cE '^[[:space:]]*episodes:' <<<"$eval_block")" = 1 ] || fail "eval.episodes set more than once: $eval_block"
grep -qxF "  episodes: 60" <<<"$eval_block" || fail "eval.episodes not 60: $eval_block"
grep -qxF "  final_episodes: 100" <<<"$eval_block" || fail "another field of eval dropped: $eval_block"
grep -qx "seed: 7" "$c" || fail "seed line"
grep -qF 'stop { eval_goal { metric: "success" at_least: 0.95 } max_seconds: 150 }' "$c" || fail "stop block"
echo "bench_seeds report: ok"
