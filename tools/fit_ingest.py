#!/usr/bin/env python3
"""Batches the learner accepted while it fitted: from RUN/events.jsonl of a PPO run.

Each PPO fit is a progress event (a learner.csv row) with its start (elapsed_s) and length
(fit_seconds); the ingest thread writes its counters (batches_ok, env_steps) at most once a second.
Two ingest events inside one fit's window bound from below what was accepted during that fit. The
learner also writes a busy event for each pass of its loop of 0.1 s or more (a fit), with the
batches the ingest thread accepted during it: exact, for fits shorter than a second too.

  tools/fit_ingest.py RUN_DIR [--min-fit-seconds S]

Prints one line per fit long enough to hold two ingest events, the totals, then the busy passes'
totals. Exit code 0; 2 when the run has no events.jsonl or no fit.
"""
import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import run_events  # noqa: E402  (beside this file)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run")
    ap.add_argument("--min-fit-seconds", type=float, default=0.0)
    a = ap.parse_args()
    if not os.path.exists(os.path.join(a.run, "events.jsonl")):
        print(f"fit_ingest: no {a.run}/events.jsonl", file=sys.stderr)
        return 2
    ev = run_events.read(a.run)
    fits = [e for e in ev if e.get("event") == "progress" and isinstance(e.get("fit_seconds"), (int, float))
            and e["fit_seconds"] >= a.min_fit_seconds]
    ingest = [e for e in ev if e.get("event") == "ingest"]
    if not fits:
        print(f"fit_ingest: no fit in {a.run}/events.jsonl", file=sys.stderr)
        return 2
    total_s = sum(f["fit_seconds"] for f in fits)
    batches = steps = with_data = 0
    print(f"{'fit':>5} {'start s':>9} {'fit s':>7} {'ingest events':>14} {'batches in fit':>15} {'env steps':>10}")
    for f in fits:
        t0, t1 = f["elapsed_s"], f["elapsed_s"] + f["fit_seconds"]
        inside = [e for e in ingest if t0 < e["elapsed_s"] < t1]
        if len(inside) < 2:
            continue
        b = inside[-1]["batches_ok"] - inside[0]["batches_ok"]
        s = inside[-1]["env_steps"] - inside[0]["env_steps"]
        batches += b
        steps += s
        with_data += b > 0
        print(f"{f.get('fit', '?'):>5} {t0:9.2f} {f['fit_seconds']:7.2f} {len(inside):14d} {b:15d} {s:10d}")
    print(f"fit_ingest: {len(fits)} fits, {total_s:.1f} s fitting; {with_data} fits with batches accepted while "
          f"they ran; at least {batches} batches ({steps} env steps) accepted during fits")
    busy = [e for e in ev if e.get("event") == "busy" and e.get("seconds", 0) >= a.min_fit_seconds]
    if busy:
        taken = [e.get("batches_accepted", 0) for e in busy]
        print(f"fit_ingest: busy passes {len(busy)}, {sum(e['seconds'] for e in busy):.1f} s; "
              f"{sum(1 for b in taken if b > 0)} with batches accepted during them; {sum(taken)} batches "
              f"({sum(e.get('env_steps_accepted', 0) for e in busy)} env steps) accepted during them")
    return 0


if __name__ == "__main__":
    sys.exit(main())
