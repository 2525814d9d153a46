#!/usr/bin/python3
"""Charts of a farm run, as PNG files next to the data (Debian python3-matplotlib):
  learning_curve.png  mean training return and evaluation return against wall time and env steps;
                      for runs whose task reports per-episode metrics (PPO: train_* / eval_*
                      columns), those metrics too
  throughput.png      env steps/s at the learner and updates/s against time; with a monitor log,
                      also each worker's steps/s and the workers' total
  --compare OUT.png   seeds side by side instead: for each RUN_DIR, the evaluation's linear
                      tracking and the training episodes' falls (terminations per fit) against env
                      steps and wall time; prints where each run first reaches the walking
                      threshold (--walking LIN,FELL: eval_tracking_lin >= LIN, eval_fell < FELL;
                      docs/record/quadrupeds.md)
usage: deploy/plot-run.py RUN_DIR [--monitor-log FILE] [--out DIR]
       deploy/plot-run.py RUN_DIR [RUN_DIR ...] --compare OUT.png [--walking 0.6,0.1]
  RUN_DIR holds learner.csv (runs/<experiment>/); FILE is a `farm-monitor --log FILE` JSON-lines log.
Runs with /usr/bin/python3, where Debian installs matplotlib."""
import argparse
import csv
import json
import math
import os
import sys

try:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
except ImportError:
    sys.exit("plot-run: matplotlib is missing: apt-get install python3-matplotlib "
             "(deploy/install-deps.sh), and run with /usr/bin/python3")


def number(s):
    try:
        x = float(s)
    except (TypeError, ValueError):
        return math.nan
    return x


def read_learner_csv(path):
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    need = {"elapsed_s", "env_steps", "mean_return", "eval_return"}
    if rows and not need <= set(rows[0]):
        sys.exit(f"plot-run: {path} lacks the columns {sorted(need - set(rows[0]))}")
    if not rows:
        sys.exit(f"plot-run: {path} has no rows yet")
    cols = {k: [number(r.get(k)) for r in rows] for k in rows[0]}
    if "env_steps_per_s" not in cols:  # PPO rows are fits: the rate between consecutive rows
        t, n = cols["elapsed_s"], cols["env_steps"]
        cols["env_steps_per_s"] = [math.nan] + [(n[i] - n[i - 1]) / (t[i] - t[i - 1]) if t[i] > t[i - 1] else math.nan
                                                for i in range(1, len(t))]
    return cols


def read_monitor_log(path):
    """(times in s from the first line, {worker id: [(t, steps/s)]}, [(t, total steps/s)])."""
    workers, totals, t0 = {}, [], None
    with open(path) as f:
        for lineno, line in enumerate(f, 1):
            line = line.strip()
            if not line:
                continue
            try:
                rec = json.loads(line)
            except json.JSONDecodeError as e:
                sys.exit(f"plot-run: {path}:{lineno}: not a JSON line ({e})")
            t = rec.get("unix_time")
            t = number(t) if t is not None else math.nan
            if math.isnan(t):
                t = number(rec.get("elapsed_s"))
            if t0 is None:
                t0 = t
            t -= t0
            for w in rec.get("workers", []):
                rate = w.get("steps_per_s") if w.get("alive") else None
                workers.setdefault(w["id"], []).append((t, rate if rate is not None else math.nan))
            totals.append((t, number(rec.get("totals", {}).get("steps_per_s"))))
    if not totals:
        sys.exit(f"plot-run: {path} has no lines")
    return workers, totals


def finite(xs, ys):
    pts = [(x, y) for x, y in zip(xs, ys) if not (math.isnan(x) or math.isnan(y))]
    return [p[0] for p in pts], [p[1] for p in pts]


def first_walking(c, lin, fell):
    """(elapsed_s, env_steps, fit) of the first evaluation with eval_tracking_lin >= lin and
    eval_fell < fell, or None."""
    for i, (l, f) in enumerate(zip(c["eval_tracking_lin"], c["eval_fell"])):
        if not math.isnan(l) and not math.isnan(f) and l >= lin and f < fell:
            return c["elapsed_s"][i], c["env_steps"][i], c["fit"][i]
    return None


def compare(run_dirs, out, walking):
    try:
        lin, fell = (float(v) for v in walking.split(","))
    except ValueError:
        sys.exit(f"plot-run: --walking wants LIN,FELL (e.g. 0.6,0.1), got '{walking}'")
    fig, axes = plt.subplots(2, 2, figsize=(12, 9), squeeze=False)
    for d in run_dirs:
        path = os.path.join(d, "learner.csv")
        if not os.path.isfile(path):
            sys.exit(f"plot-run: no learner.csv in {d}")
        c = read_learner_csv(path)
        missing = [k for k in ("eval_tracking_lin", "eval_fell", "train_fell", "fit") if k not in c]
        if missing:
            sys.exit(f"plot-run: {path} lacks {missing} (--compare is for the legged tasks' PPO runs)")
        name = os.path.basename(os.path.normpath(d))
        hit = first_walking(c, lin, fell)
        print(f"plot-run: {name}: " + (f"walking (eval_tracking_lin >= {lin}, eval_fell < {fell}) first at "
                                        f"{hit[0]:.0f} s, {hit[1]:,.0f} env steps, fit {hit[2]:.0f}" if hit else
                                        f"never reaches eval_tracking_lin >= {lin} with eval_fell < {fell}") +
              f"; end {c['elapsed_s'][-1]:.0f} s, {c['env_steps'][-1]:,.0f} env steps")
        for col, (xkey, xlabel) in enumerate((("env_steps", "env steps"), ("elapsed_s", "wall time (s)"))):
            x, y = finite(c[xkey], c["eval_tracking_lin"])
            line, = axes[0][col].plot(x, y, "o-", markersize=2, label=name)
            if hit:
                axes[0][col].axvline(hit[0 if xkey == "elapsed_s" else 1], color=line.get_color(), alpha=0.4, ls=":")
            x, y = finite(c[xkey], c["train_fell"])
            axes[1][col].plot(x, y, "-", color=line.get_color(), label=name)
            axes[1][col].set_xlabel(xlabel)
    for col in range(2):
        axes[0][col].axhline(lin, color="black", ls="--", linewidth=1, label=f"walking: {lin}")
        axes[0][col].set_ylabel("eval_tracking_lin (deterministic evaluation)")
        axes[1][col].set_ylabel("train_fell (share of training episodes ending in a fall)")
        for r in range(2):
            axes[r][col].grid(alpha=0.3)
    axes[0][0].legend(fontsize=8, loc="upper left")
    fig.suptitle("seeds side by side: linear tracking and falls")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    print(f"plot-run: wrote {out}")


def main():
    ap = argparse.ArgumentParser(description="PNG charts of a farm run (learner.csv, farm-monitor log).")
    ap.add_argument("run_dir", nargs="+", help="the run directory with learner.csv (several with --compare)")
    ap.add_argument("--monitor-log", help="a farm-monitor --log JSON-lines file")
    ap.add_argument("--out", help="where the PNGs go (default: RUN_DIR)")
    ap.add_argument("--compare", metavar="OUT.png", help="seeds side by side (legged PPO runs) into one PNG")
    ap.add_argument("--walking", default="0.6,0.1", help="walking threshold LIN,FELL for --compare")
    a = ap.parse_args()
    if a.compare:
        return compare(a.run_dir, a.compare, a.walking)
    if len(a.run_dir) > 1:
        sys.exit("plot-run: one RUN_DIR, or several with --compare OUT.png")
    a.run_dir = a.run_dir[0]
    csv_path = os.path.join(a.run_dir, "learner.csv")
    if not os.path.isfile(csv_path):
        sys.exit(f"plot-run: no learner.csv in {a.run_dir}")
    out = a.out or a.run_dir
    os.makedirs(out, exist_ok=True)
    c = read_learner_csv(csv_path)
    name = os.path.basename(os.path.normpath(a.run_dir))

    # The task's per-episode metrics (PPO runs: train_<metric>, eval_<metric>) get a second row.
    metrics = [k[len("train_"):] for k in c if k.startswith("train_") and k != "train_time_s"]
    rows = 2 if metrics else 1
    fig, axes = plt.subplots(rows, 2, figsize=(12, 4.5 * rows), squeeze=False)
    ax_t, ax_s = axes[0]
    if metrics:
        for ax, xkey, xlabel in ((axes[1][0], "elapsed_s", "wall time (s)"), (axes[1][1], "env_steps", "env steps")):
            for m in metrics:
                x, y = finite(c[xkey], c["train_" + m])
                if x:
                    line, = ax.plot(x, y, "-", label=f"{m} (training episodes)")
                    x, y = finite(c[xkey], c.get("eval_" + m, []))
                    if x:
                        ax.plot(x, y, "o--", color=line.get_color(), markersize=3, label=f"{m} (evaluation)")
            ax.set_xlabel(xlabel)
            ax.set_ylabel("per-episode metric")
            ax.grid(alpha=0.3)
        axes[1][0].legend(loc="best", fontsize=7)
    for ax, xkey, xlabel in ((ax_t, "elapsed_s", "wall time (s)"), (ax_s, "env_steps", "env steps")):
        for ykey, label, style in (("mean_return", "training return (mean of last 100 episodes)", "-"),
                                   ("eval_return", "evaluation return (deterministic)", "o-")):
            x, y = finite(c[xkey], c[ykey])
            if x:
                ax.plot(x, y, style, label=label, markersize=3)
        ax.set_xlabel(xlabel)
        ax.set_ylabel("return")
        ax.grid(alpha=0.3)
    ax_t.legend(loc="lower right", fontsize=8)
    fig.suptitle(f"{name}: learning curve")
    fig.tight_layout()
    curve = os.path.join(out, "learning_curve.png")
    fig.savefig(curve, dpi=110)
    plt.close(fig)

    monitor = read_monitor_log(a.monitor_log) if a.monitor_log else None
    fig, axes = plt.subplots(1, 2 if monitor else 1, figsize=(12 if monitor else 7, 4.5), squeeze=False)
    ax = axes[0][0]
    x, y = finite(c["elapsed_s"], c["env_steps_per_s"])
    ax.plot(x, y, label="env steps/s in (learner)")
    ax.set_xlabel("wall time (s)")
    ax.set_ylabel("env steps/s")
    if "updates_per_s" in c:
        ax2 = ax.twinx()
        x, y = finite(c["elapsed_s"], c["updates_per_s"])
        ax2.plot(x, y, color="tab:red", alpha=0.7, label="updates/s")
        ax2.set_ylabel("updates/s")
        ax.legend(handles=ax.get_lines() + ax2.get_lines(), loc="lower right", fontsize=8)
    else:
        ax.legend(loc="lower right", fontsize=8)
    ax.grid(alpha=0.3)
    ax.set_title("learner (learner.csv)")
    if monitor:
        workers, totals = monitor
        ax = axes[0][1]
        for wid in sorted(workers):
            x, y = zip(*workers[wid])
            ax.plot(x, y, label=wid, linewidth=1)
        x, y = finite(*zip(*totals))
        ax.plot(x, y, color="black", linewidth=2, label="total (live workers)")
        ax.set_xlabel("time since the monitor's first line (s)")
        ax.set_ylabel("env steps/s")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="best")
        ax.set_title("workers (farm-monitor log)")
    fig.suptitle(f"{name}: throughput")
    fig.tight_layout()
    thr = os.path.join(out, "throughput.png")
    fig.savefig(thr, dpi=110)
    plt.close(fig)
    print(f"plot-run: wrote {curve} and {thr}")


if __name__ == "__main__":
    main()
