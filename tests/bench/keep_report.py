#!/usr/bin/env python3
"""Whether training runs keep what they reach, from their learners' events.jsonl.

Per run: the time the first evaluation at or above GOAL was asked, the kept best (the highest
score of its `best` events, else of its evaluations), the final evaluation, and the lowest
evaluation from the goal's on. A run keeps the goal where its final evaluation and every
evaluation from the goal's on are within WITHIN (a fraction of |best|) of the kept best. Only
confirmed evaluations count.
  keep_report.py --goal 12000 [--within 0.1] LABEL=RUN/learner/events.jsonl ...
Prints one table row per run and a last line with how many reached the goal and kept it.
"""
import argparse
import json
import sys


def read_run(path):
    evals, bests = [], []
    with open(path) as f:
        for line in f:
            try:
                e = json.loads(line)
            except ValueError:
                continue  # a line cut by a killed run
            if e.get("event") == "evaluation" and e.get("confirmed", True):
                evals.append(e)
            elif e.get("event") == "best":
                bests.append(e["score"])
    return evals, bests


def report(label, path, goal, within):
    evals, bests = read_run(path)
    if not evals:
        return f"| {label} | - | - | - | - | no evaluations |", False
    best = max(bests) if bests else max(e["mean"] for e in evals)
    final = next((e["mean"] for e in reversed(evals) if e.get("label") == "final"), None)
    first = next((i for i, e in enumerate(evals) if e["mean"] >= goal), None)
    floor = best - within * abs(best)
    if first is None:
        fin = "-" if final is None else f"{final:.1f}"
        return f"| {label} | - | {best:.1f} | {fin} | - | goal not reached |", False
    after = [e["mean"] for e in evals[first:]]
    low = min(after)
    kept = low >= floor and (final is None or final >= floor)
    t = evals[first].get("asked_elapsed_s", evals[first]["elapsed_s"])
    fin = "-" if final is None else f"{final:.1f} ({final / best:.2f})"
    verdict = "kept" if kept else f"not kept: below {floor:.1f}"
    return f"| {label} | {t:.1f} s | {best:.1f} | {fin} | {low:.1f} ({low / best:.2f}) | {verdict} |", kept


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--goal", type=float, required=True, help="the evaluation return to reach")
    p.add_argument("--within", type=float, default=0.1, help="fraction of |kept best| a later evaluation may lose")
    p.add_argument("runs", nargs="+", help="LABEL=path/to/events.jsonl")
    a = p.parse_args()
    print(f"goal {a.goal:g}, kept within {a.within:g} of the kept best")
    print("| run | time to goal | kept best | final (/ best) | lowest from the goal on (/ best) | verdict |")
    print("|---|---|---|---|---|---|")
    reached = kept = 0
    for run in a.runs:
        label, _, path = run.partition("=")
        try:
            row, ok = report(label, path, a.goal, a.within)
        except OSError as e:
            row, ok = f"| {label} | cannot read {path}: {e.strerror} |", False
        print(row)
        reached += "goal not reached" not in row and "no evaluations" not in row and "cannot read" not in row
        kept += ok
    print(f"{reached} of {len(a.runs)} runs reached {a.goal:g}; {kept} kept it")
    return 0


if __name__ == "__main__":
    sys.exit(main())
