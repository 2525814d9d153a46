#!/usr/bin/env bash
# farm-mclari-eval on a real checkpoint: a learner and a worker (real DDS) train the swept mCLARI
# config for a few seconds with 6-step episodes and collects longer than the heartbeat timeout; the evaluation prints the six-terrain table and
# --trace writes each step's gait, which must lie in the config's group set and frequency range.
# The learner's best policy (run/best) evaluates as the checkpoint when the final evaluation was its only one.
# That evaluation (6 episodes, split over two workers) covers each terrain once, the second part
# going on where the first ended, and the best is kept by its worst episode's share of the reference,
# which the run's events record.
# A small sweep's best.csv gives the comparison column, and the table says when the sweep's runs
# were not as long as the episodes.
# usage: test_mclari_eval.sh LEARNER WORKER EVAL SOURCE_DIR SWEEP
set -euo pipefail
LEARNER=$1 WORKER=$2 EVAL=$3 SRC=$4 SWEEP=$5
# Only the processes this test started are ended, by their ids (not every process on domain 94):
# a bystander whose command line says "--domain 94" must outlive the test's clean-up.
T=$(mktemp -d); PIDS=()
cleanup() { for p in "${PIDS[@]}"; do kill "$p" 2>/dev/null || true; done; }
trap 'cleanup; kill $BYSTANDER 2>/dev/null; rm -rf "$T"' EXIT
(exec -a "bystander --domain 94" sleep 600) &
BYSTANDER=$!
fail() { echo "FAIL: $*"; exit 1; }
sed -e 's/max_seconds: 1500/max_seconds: 8/' -e 's/every_seconds: 600/every_seconds: 100000/' \
    -e 's/final_episodes: 6/final_episodes: 6 min_episodes_per_worker: 3 best_metric: "share" best_reduce: "min"/' \
    -e 's/    groups: \[5, 11, 15, 19, 20, 23\]/    groups: [5, 11, 15, 19, 20, 23]\n    max_episode_steps: 6/' \
    -e 's/^  steps_per_batch: 4$/  steps_per_batch: 16/' \
    "$SRC/deploy/configs/mclari_sac_swept.txtpb" > "$T/c.txtpb"
grep -q "max_episode_steps: 6" "$T/c.txtpb" || fail "could not shorten the episodes of the swept config"
grep -q "^  steps_per_batch: 16$" "$T/c.txtpb" || fail "could not lengthen the batches of the swept config"
# Collects of 16 steps x 4 envs of 1 s each take the workers 6-8 s here (8-11 steps/s), twice the
# heartbeat timeout (3 s) or more: the workers stay live all the same (heartbeats beside the
# loop), and the parts of the evaluation they hold are not given up.
echo "worker_timeout_seconds: 3" >> "$T/c.txtpb"
"$LEARNER" --config "$T/c.txtpb" --run-dir "$T/run" --domain 94 > "$T/learner.log" 2>&1 &
L=$!; PIDS+=($L)
"$WORKER" --domain 94 --id eval1 > "$T/worker.log" 2>&1 &
PIDS+=($!)
"$WORKER" --domain 94 --id eval2 > "$T/worker2.log" 2>&1 &
PIDS+=($!)
wait $L || { tail -20 "$T/learner.log"; fail "learner failed"; }
[ -d "$T/run/checkpoint/sac" ] || fail "no checkpoint in $T/run"
grep -q "^evaluations       asked 2, answered 2, lost 0, invalid 0" "$T/run/summary.txt" \
    || { cat "$T/run/summary.txt"; fail "evaluations asked, answered or lost"; }
grep -q "^best eval share (min) *[0-9.]*$" "$T/run/summary.txt" || { cat "$T/run/summary.txt"; fail "summary: no best share"; }
grep -q 'best_eval_measure: "share (min)"' "$T/run/best/manifest.txtpb" \
    || { cat "$T/run/best/manifest.txtpb"; fail "run/best does not say what it is the best of"; }
# From the run's events: the final evaluation split over both workers, terrains 0..5 once each (a
# mean terrain of 2.5; both parts from terrain 0 would give 1.0), no live worker marked dead during a
# long collect, and the best kept by the worst share: the score of the run's one evaluation.
best=$(sed -n 's/^best eval share (min) *\([0-9.]*\)$/\1/p' "$T/run/summary.txt")
python3 - "$T/run/events.jsonl" "$best" <<'PY' || { tail -20 "$T/learner.log"; fail "events: see above"; }
import json, sys
ev = [json.loads(l) for l in open(sys.argv[1]) if l.strip()]
kind = lambda k: [e for e in ev if e["event"] == k]
final = [e for e in kind("evaluation") if e.get("label") == "final"]
bad = []
if len(final) != 1 or final[0].get("episodes") != 6 or final[0].get("workers", 0) < 2:
    bad.append("the final evaluation was not 6 episodes split over the 2 workers: %s" % final)
elif abs(final[0]["metrics"]["terrain"] - 2.5) > 1e-6:
    bad.append("the final evaluation did not run each terrain once: terrain %s" % final[0]["metrics"]["terrain"])
if [e for e in kind("worker") if e.get("change") == "dead"]:
    bad.append("a live worker was marked dead during a long collect")
best = kind("best")
if not best or best[-1]["measure"] != "share (min)":
    bad.append("the best was not kept by the worst share: %s" % best)
elif "%.4f" % best[-1]["score"] != sys.argv[2]:
    bad.append("best event score %.4f, summary %s" % (best[-1]["score"], sys.argv[2]))
evals = [e for e in kind("evaluation") if e.get("episodes", 0) > 0]
if len(evals) != 1 or "%.4f" % evals[0]["metrics_min"]["share"] != sys.argv[2]:
    bad.append("the one evaluation's worst share is not the best kept: %s" % evals)
for b in bad:
    print("FAIL:", b)
sys.exit(1 if bad else 0)
PY

"$EVAL" --config "$T/c.txtpb" --checkpoint "$T/run/checkpoint" --episodes 2 --threads 2 \
    --trace "$T/trace.csv" > "$T/eval.out" 2> "$T/eval.err" || { cat "$T/eval.err"; fail "evaluation failed"; }
for t in plain-normal plain-wet plain-dry rough-normal rough-wet rough-dry; do
  grep -q "^| $t | 2 | " "$T/eval.out" || { cat "$T/eval.out"; fail "no table row for $t"; }
done
grep -q "^trace: " "$T/eval.out" || fail "no trace line"
python3 - "$T/trace.csv" <<'PY'
import csv, math, sys
rows = list(csv.DictReader(open(sys.argv[1])))
assert rows, "empty trace"
assert list(rows[0].keys()) == ["terrain", "terrain_name", "step", "frequency_hz", "group", "group_name",
                                "power_w", "speed_mm_s", "efficiency", "reward", "end"], rows[0].keys()
by = {}
for r in rows:
    by.setdefault(int(r["terrain"]), []).append(r)
    assert int(r["group"]) in (5, 11, 15, 19, 20, 23), "group outside the config's set: %s" % r
    assert 1 <= int(r["frequency_hz"]) <= 150, r
    e = float(r["efficiency"])
    assert math.isfinite(e) and e >= 0, r
assert sorted(by) == list(range(6)), sorted(by)
for t, rs in by.items():
    assert [int(r["step"]) for r in rs] == list(range(1, len(rs) + 1)), (t, [r["step"] for r in rs])
    assert 1 <= len(rs) <= 6, (t, len(rs))
    assert rs[-1]["end"] in ("terminated", "truncated") and all(r["end"] == "" for r in rs[:-1]), (t, rs[-1])
print("trace ok: %d steps over 6 terrains" % len(rows))
PY

# The learner kept its best evaluation's networks in run/best. Its one evaluation was the final
# one, after the last update, so they are the checkpoint's networks: the same table.
[ -d "$T/run/best/sac" ] || fail "no best policy in $T/run"
"$EVAL" --config "$T/c.txtpb" --checkpoint "$T/run/best" --episodes 2 --threads 2 > "$T/best.out" 2> "$T/best.err" \
    || { cat "$T/best.err"; fail "evaluation of run/best failed"; }
diff <(grep '^| ' "$T/eval.out") <(grep '^| ' "$T/best.out") || fail "run/best does not evaluate as the checkpoint"

# The comparison with a sweep: runs as long as the episodes (6 s) compare without a note, 2 s ones
# get the note that names both lengths.
for secs in 6 2; do
  "$SWEEP" --out "$T/sweep$secs" --config "$T/c.txtpb" --seconds $secs --frequencies 1 --groups 11,20 \
      --threads 2 > "$T/sweep$secs.out" 2>&1 || { cat "$T/sweep$secs.out"; fail "sweep failed"; }
  "$EVAL" --config "$T/c.txtpb" --checkpoint "$T/run/checkpoint" --episodes 1 --threads 2 \
      --best "$T/sweep$secs/best.csv" > "$T/cmp$secs.out" 2> /dev/null || fail "evaluation with --best failed"
  [ "$(grep -c ', 1 Hz | ' "$T/cmp$secs.out")" = 6 ] || { cat "$T/cmp$secs.out"; fail "no best fixed point per terrain"; }
done
grep -q "not like for like" "$T/cmp6.out" && { cat "$T/cmp6.out"; fail "note on equal lengths"; }
grep -q "ran 2 s, these episodes up to 6 s" "$T/cmp2.out" || { cat "$T/cmp2.out"; fail "no note on unequal lengths"; }

# A trace that cannot be written is named.
if "$EVAL" --config "$T/c.txtpb" --checkpoint "$T/run/checkpoint" --episodes 1 --threads 2 \
    --trace "$T/no/such/dir/trace.csv" > /dev/null 2> "$T/err.txt"; then fail "unwritable trace accepted"; fi
grep -q "no/such/dir/trace.csv" "$T/err.txt" || { cat "$T/err.txt"; fail "error does not name the trace path"; }
cleanup
sleep 0.5
kill -0 $BYSTANDER 2>/dev/null || fail "the clean-up ended a process this test did not start"
echo "PASS"
