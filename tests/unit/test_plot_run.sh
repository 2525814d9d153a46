#!/usr/bin/env bash
# deploy/plot-run.py --compare: the walking threshold crossing it prints (first evaluation with
# eval_tracking_lin >= LIN and eval_fell < FELL, both conditions), the PNG, and the errors.
# usage: test_plot_run.sh SOURCE_DIR
set -euo pipefail
SRC=$1
T=$(mktemp -d); trap 'rm -rf "$T"' EXIT
fail() { echo "FAIL: $*"; exit 1; }
mkdir -p "$T/a" "$T/b"
H=elapsed_s,fit,env_steps,mean_return,eval_return,train_fell,eval_tracking_lin,eval_fell
# a: fit 2 tracks well but falls (0.25), fit 3 has no evaluation (nan), fit 4 is the first crossing.
cat > "$T/a/learner.csv" <<CSV
$H
10.5,1,1000,1.0,nan,0.9,0.2,0
20.5,2,2000,2.0,3.0,0.5,0.7,0.25
30.5,3,3000,3.0,nan,0.4,nan,nan
40.5,4,4000,4.0,5.0,0.3,0.6,0.0
50.5,5,5000,5.0,6.0,0.2,0.9,0.0
CSV
# b: never both at once.
cat > "$T/b/learner.csv" <<CSV
$H
10,1,1500,1.0,2.0,0.9,0.59,0
20,2,3000,2.0,3.0,0.5,0.8,0.1
CSV
out=$(/usr/bin/python3 "$SRC/deploy/plot-run.py" "$T/a" "$T/b" --compare "$T/seeds.png")
echo "$out"
grep -q "a: walking (eval_tracking_lin >= 0.6, eval_fell < 0.1) first at 40 s, 4,000 env steps, fit 4; end 50 s, 5,000 env steps" <<< "$out" \
  || fail "run a: expected the crossing at fit 4"
grep -q "b: never reaches eval_tracking_lin >= 0.6 with eval_fell < 0.1" <<< "$out" || fail "run b: expected no crossing"
[ -s "$T/seeds.png" ] || fail "no PNG written"
# A looser threshold moves the crossing to fit 2 (falls below 0.3 allowed).
out=$(/usr/bin/python3 "$SRC/deploy/plot-run.py" "$T/a" --walking 0.7,0.3 --compare "$T/x.png")
grep -q "first at 20 s, 2,000 env steps, fit 2" <<< "$out" || fail "--walking 0.7,0.3: expected fit 2: $out"
# Errors name what is wrong and exit non-zero.
if err=$(/usr/bin/python3 "$SRC/deploy/plot-run.py" "$T/a" --walking high --compare "$T/y.png" 2>&1); then fail "bad --walking accepted"; fi
grep -q "walking wants LIN,FELL" <<< "$err" || fail "bad --walking: $err"
if err=$(/usr/bin/python3 "$SRC/deploy/plot-run.py" "$T/a" "$T/missing" --compare "$T/y.png" 2>&1); then fail "missing run accepted"; fi
grep -q "no learner.csv in $T/missing" <<< "$err" || fail "missing run: $err"
echo "plot-run --compare: ok"
