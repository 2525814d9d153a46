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
# What the learner and the evaluation did is read from their records: the run's events.jsonl
# (learner/events.h) and farm-mclari-eval's --events (its kinds: tools/mclari_eval.cpp).
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
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"  # its events readers; this test's own fail follows
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
grep -q 'best_eval_measure: "share (min)"' "$T/run/best/manifest.txtpb" \
    || { cat "$T/run/best/manifest.txtpb"; fail "run/best does not say what it is the best of"; }
# From the run's events: its summary counts 2 evaluations asked and answered, none lost or invalid,
# and a best share (min); the final evaluation split over both workers, terrains 0..5 once each (a
# mean terrain of 2.5; both parts from terrain 0 would give 1.0), no live worker marked dead during a
# long collect, and the best kept by the worst share: the score of the run's one evaluation.
python3 - "$T/run/events.jsonl" <<'PY' || { tail -20 "$T/learner.log"; fail "events: see above"; }
import json, sys
ev = [json.loads(l) for l in open(sys.argv[1]) if l.strip()]
kind = lambda k: [e for e in ev if e["event"] == k]
bad = []
summary = (kind("summary") or [{}])[-1]
counts = {k: summary.get(k) for k in ("evals_asked", "evals_answered", "evals_lost", "evals_invalid")}
if counts != {"evals_asked": 2, "evals_answered": 2, "evals_lost": 0, "evals_invalid": 0}:
    bad.append("evaluations asked, answered or lost: %s" % counts)
best_eval = summary.get("best_eval")
if summary.get("best_measure") != "share (min)" or not isinstance(best_eval, (int, float)) or best_eval < 0:
    bad.append("summary: no best share (min): %s" % summary)
    best_eval = float("nan")
final = [e for e in kind("evaluation") if e.get("label") == "final"]
if len(final) != 1 or final[0].get("episodes") != 6 or final[0].get("workers", 0) < 2:
    bad.append("the final evaluation was not 6 episodes split over the 2 workers: %s" % final)
elif abs(final[0]["metrics"]["terrain"] - 2.5) > 1e-6:
    bad.append("the final evaluation did not run each terrain once: terrain %s" % final[0]["metrics"]["terrain"])
if [e for e in kind("worker") if e.get("change") == "dead"]:
    bad.append("a live worker was marked dead during a long collect")
best = kind("best")
if not best or best[-1]["measure"] != "share (min)":
    bad.append("the best was not kept by the worst share: %s" % best)
elif best[-1]["score"] != best_eval:
    bad.append("best event score %r, summary %r" % (best[-1]["score"], best_eval))
evals = [e for e in kind("evaluation") if e.get("episodes", 0) > 0]
if len(evals) != 1 or "%.4f" % evals[0]["metrics_min"]["share"] != "%.4f" % best_eval:
    bad.append("the one evaluation's worst share is not the best kept: %s" % evals)
for b in bad:
    print("FAIL:", b)
sys.exit(1 if bad else 0)
PY

"$EVAL" --config "$T/c.txtpb" --checkpoint "$T/run/checkpoint" --episodes 2 --threads 2 \
    --trace "$T/trace.csv" --events "$T/eval.jsonl" > "$T/eval.out" 2> "$T/eval.err" \
    || { cat "$T/eval.err"; fail "evaluation failed"; }
cat "$T/eval.out"
for t in plain-normal plain-wet plain-dry rough-normal rough-wet rough-dry; do
  has_event "$T/eval.jsonl" row terrain_name="\"$t\"" episodes=2 || { cat "$T/eval.jsonl"; fail "no table row for $t"; }
done
has_event "$T/eval.jsonl" trace path="\"$T/trace.csv\"" episodes=6 || fail "no trace written"
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
"$EVAL" --config "$T/c.txtpb" --checkpoint "$T/run/best" --episodes 2 --threads 2 --events "$T/best.jsonl" \
    > /dev/null 2> "$T/best.err" || { cat "$T/best.err"; fail "evaluation of run/best failed"; }
events_same_but_time "$T/eval.jsonl" "$T/best.jsonl" row || fail "run/best does not evaluate as the checkpoint"

# The comparison with a sweep: runs as long as the episodes (6 s) compare without a note, 2 s ones
# get the note that names both lengths.
for secs in 6 2; do
  "$SWEEP" --out "$T/sweep$secs" --config "$T/c.txtpb" --seconds $secs --frequencies 1 --groups 11,20 \
      --threads 2 > "$T/sweep$secs.out" 2>&1 || { cat "$T/sweep$secs.out"; fail "sweep failed"; }
  "$EVAL" --config "$T/c.txtpb" --checkpoint "$T/run/checkpoint" --episodes 1 --threads 2 \
      --best "$T/sweep$secs/best.csv" --events "$T/cmp$secs.jsonl" > "$T/cmp$secs.out" 2> /dev/null \
      || fail "evaluation with --best failed"
  cat "$T/cmp$secs.out"
  python3 -c '
import json, sys
rows = [e for e in map(json.loads, open(sys.argv[1])) if e["event"] == "row"]
sys.exit(len([r for r in rows if r["fixed"] and r["fixed"]["frequency_hz"] == 1 and r["fixed"]["group_name"]]) != 6)
' "$T/cmp$secs.jsonl" || { cat "$T/cmp$secs.jsonl"; fail "no best fixed point per terrain"; }
done
event_of "$T/cmp6.jsonl" note 'e' && fail "note on equal lengths"
has_event "$T/cmp2.jsonl" note kind='"unequal_lengths"' ran_s=2 episodes_up_to_s=6 \
    || { cat "$T/cmp2.jsonl"; fail "no note on unequal lengths"; }

# A trace that cannot be written is named.
if "$EVAL" --config "$T/c.txtpb" --checkpoint "$T/run/checkpoint" --episodes 1 --threads 2 \
    --trace "$T/no/such/dir/trace.csv" > /dev/null 2> "$T/err.txt"; then fail "unwritable trace accepted"; fi
grep -q "no/such/dir/trace.csv" "$T/err.txt" || { cat "$T/err.txt"; fail "error does not name the trace path"; }
cleanup
sleep 0.5
kill -0 $BYSTANDER 2>/dev/null || fail "the clean-up ended a process this test did not start"
echo "PASS"
