#!/usr/bin/python3
"""Trains one shipped config over several seeds and reports every seed, with the spread.

  tools/seeds.py CONFIG [--seeds 1,2,3] [--workers W] [--parallel P] [--out DIR] [--domain D]
                 [--build DIR] [--learner-bin PATH] [--worker-bin PATH] [--eval-episodes N]
                 [--cpus-per-run C] [--gpus 0,1,..] [--train-only | --report-only] [--resume]

For each seed the config is copied with only its `seed:` line changed, a learner and W workers run
it on this host (shared memory only, deploy/discovery/local.xml, DDS domain D + seed), P runs side
by side; with --cpus-per-run C the k-th of them (its learner and workers) is held to cores
k*C .. (k+1)*C - 1 (taskset), with --gpus the k-th gets the k-th GPU (CUDA_VISIBLE_DEVICES): one
host of 4 x 16 cores and 4 GPUs runs 4 seeds as 4 16-core one-GPU hosts would, apart from what
they share (memory bandwidth, caches). Then each run's final policy (RUN/checkpoint) and kept best (RUN/best) are measured on the
task's own goal:
  pendulum, cart-pole   evaluation return (learner.csv) against stop.target_eval_return
  a1, honey_badger,     the walking threshold of docs/record/quadrupeds.md: eval_tracking_lin >= 0.6 and
  silver_badger         eval_fell < 0.1 (learner.csv; measure: eval_tracking_lin)
  jetbot, kaya          success over --eval-episodes (default 100) fresh maps, farm-mobile-eval;
                        the goal's time: the first learner evaluation at 95 % success or more
  mclari                farm-mclari-eval on the six terrains against docs/data/mclari_best_180s.csv:
                        the worst terrain's share of the best fixed point, and falls
Writes DIR/seeds.md (per-seed table, then median and interquartile mean with a 95 % bootstrap
interval over the seeds, as in Agarwal et al. 2021), DIR/seeds.csv and DIR/seeds.png (each seed's
evaluation curve against wall time and the goal: success % for mobile robots, from the learner's log;
its points in DIR/seeds_curves.csv; for the mCLARI microbot the worst terrain's share that the
learner logs for each evaluation). --report-only measures and reports runs already in DIR: a
policy's measurement (RUN/eval_final.txt, RUN/eval_best.txt) is kept and used again when the same
command made it, begun after every file the command names was written, unless --remeasure; where
RUN/best holds the final policy itself (same version, same files), it is measured once. The table names the
training's command (DIR/command.txt, written when training starts); a seed without a run folder
is reported as missing. Exit status 0 when every seed's kept best meets the goal and no learner
failed (with --train-only: when no learner failed), 1 otherwise. Runs with /usr/bin/python3
(Debian's matplotlib).

Ctrl-C, SIGINT or SIGTERM (a batch system's time limit) stops the runs in progress as the learner's
own Ctrl-C does, each with a checkpoint, starts no other, and exits with 130 (a second signal ends
them at once, without checkpoints). --resume continues
DIR: a run that ended on its own is kept as it is, one that was stopped goes on from its checkpoint
(farm-learner --resume: its time and stop limits count what it had done), a seed without a run
starts. DIR/command.txt gets each resuming command as a line of its own."""
import argparse
import csv
import filecmp
import math
import os
import random
import re
import shlex
import signal
import subprocess
import sys
import textwrap
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import run_events  # noqa: E402  (beside this file)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
WALKING_LIN, WALKING_FELL = 0.6, 0.1
MOBILE_GOAL, MCLARI_GOAL, MCLARI_FALLS = 95.0, 90.0, 0.1
SUCCESS_LABEL = "success % (learner's evaluations)"
SHARE_LABEL = "worst terrain % of the best fixed point (learner's evaluations)"


def fail(msg):
    sys.exit("seeds: " + msg)


def number(s):
    try:
        return float(s)
    except (TypeError, ValueError):
        return math.nan


# ---- the config: task name, target, seed line --------------------------------------------------

def read_config(path):
    try:
        text = open(path).read()
    except OSError as e:
        fail(f"cannot read config {path}: {e.strerror}")
    task = re.search(r'task\s*\{[^}]*?name:\s*"([^"]+)"', text, re.S)
    if not task:
        fail(f"{path}: no task {{ name: ... }} found")
    target = re.search(r"target_eval_return:\s*([-0-9.eE+]+)", text)
    if not re.search(r"^seed:\s*\d+\s*$", text, re.M):
        fail(f"{path}: no top-level `seed: N` line to change (add `seed: 1`)")
    return text, task.group(1), float(target.group(1)) if target else math.nan


def goal_kind(task):
    if task in ("pendulum", "cartpole"):
        return "return"
    if task in ("a1", "honey_badger", "silver_badger"):
        return "walking"
    if task in ("jetbot", "kaya"):
        return "mobile"
    if task == "mclari":
        return "mclari"
    fail(f"no goal known for task '{task}' (known: pendulum, cartpole, a1, honey_badger, silver_badger, "
         "jetbot, kaya, mclari)")


# ---- learner.csv --------------------------------------------------------------------------------

def read_rows(run):
    path = os.path.join(run, "learner.csv")
    try:
        with open(path) as f:
            return list(csv.DictReader(f))
    except OSError:
        return []


def eval_rows(rows, column):
    return [r for r in rows if not math.isnan(number(r.get(column)))]


def first_time(rows, ok):
    for r in rows:
        if ok(r):
            return number(r["elapsed_s"])
    return math.nan


def walking(r):
    return number(r.get("eval_tracking_lin")) >= WALKING_LIN and number(r.get("eval_fell")) < WALKING_FELL


# ---- the measures -------------------------------------------------------------------------------

def summary_value(run, field):
    """A figure of the run's summary event ("wall_s", "env_steps"), NaN where absent."""
    ev = run_events.read(run, "summary")
    return number(ev[-1].get(field)) if ev and ev[-1].get(field) is not None else math.nan


def evaluations(run, labels=("eval",)):
    """The evaluation events of a run with episodes, of the given labels, in the order answered."""
    return [e for e in run_events.read(run, "evaluation") if e.get("label") in labels and (e.get("episodes") or 0) > 0
            and e.get("mean") is not None]


def read_text(path):
    """The file's text, "" where it cannot be read (a run without a log)."""
    try:
        return open(path).read()
    except OSError:
        return ""


def eval_returns(run):
    """(elapsed s when asked, mean return) of every training evaluation of the run: learner.csv
    holds a row per log interval only (SAC, DQN), and a run that stops on its target may end
    between two rows."""
    return [(float(e["asked_elapsed_s"]), float(e["mean"])) for e in evaluations(run)]


def measure_curve(run, kind, target):
    """(time to goal, best measure, final measure, final meets goal, best meets goal): from the
    run's evaluation events (returns) or learner.csv (walking)."""
    rows = read_rows(run)
    if kind == "return":
        ev = eval_returns(run) or [(number(r["elapsed_s"]), number(r["eval_return"]))
                                for r in eval_rows(rows, "eval_return")]
        finals = evaluations(run, ("final",))
        final = float(finals[-1]["mean"]) if finals else math.nan
        if math.isnan(final) and ev:
            final = ev[-1][1]
        if math.isnan(final):  # no evaluation at all (a run that ended before its first)
            return None
        best = max([v for _, v in ev] + [final])
        return dict(time=next((t for t, v in ev if v >= target), math.nan), best=best, final=final,
                    best_ok=best >= target, final_ok=final >= target)
    ev = eval_rows(rows, "eval_tracking_lin")
    if not ev:
        return None
    upright = [r for r in ev if number(r["eval_fell"]) < WALKING_FELL] or ev
    best_row = max(upright, key=lambda r: number(r["eval_tracking_lin"]))
    return dict(time=first_time(ev, walking), best=number(best_row["eval_tracking_lin"]),
                final=number(ev[-1]["eval_tracking_lin"]), best_ok=walking(best_row), final_ok=walking(ev[-1]))


MEASUREMENT = re.compile(r"eval_[a-z]+\.txt(\.new)?$")


def newest_mtime(path):
    """The latest modification time of the file path, or of the files under the folder path (its
    own time changes with any file made in it), measurements (eval_*.txt) aside: farm-mobile-eval
    names the run folder, which holds them. A folder without such files: its own time."""
    if not os.path.isdir(path):
        return os.path.getmtime(path)
    times = [os.path.getmtime(os.path.join(d, f)) for d, _, files in os.walk(path) for f in files
             if not MEASUREMENT.match(f)]
    return max(times, default=os.path.getmtime(path))


def run_tool(cmd, log, parse, remeasure):
    """Runs cmd, its output into log (first line: the command), and returns parse(output); parse
    gives None for an incomplete output. A complete log of the same command, begun after every file
    the command names was last written (program, config, policy folder, reference), is used as it is
    unless remeasure: a measurement takes minutes. A new measurement is written to log + ".new" and
    replaces log only when complete; the log's time is then when it began."""
    head = "$ " + " ".join(cmd)
    new = log + ".new"
    if not os.path.isdir(os.path.dirname(log) or "."):
        return None  # no run folder: the report names the seed as missing
    named = [newest_mtime(x) for x in cmd if os.path.exists(x)]
    if not remeasure and os.path.exists(log) and os.path.getmtime(log) > max(named, default=0):
        text = read_text(log)
        if text.split("\n", 1)[0] == head and parse(text) is not None:
            print(f"seeds: {log}: measured already by the same command, after what it names was written: "
                  "used (--remeasure measures again)", file=sys.stderr)
            return parse(text)
    began = time.time()
    with open(new, "w") as f:
        f.write(head + "\n")
        f.flush()
        try:
            p = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        except OSError as e:
            f.write(f"cannot run {cmd[0]}: {e}\n")
            print(f"seeds: cannot run {cmd[0]}: {e.strerror} (build it, or give --build)", file=sys.stderr)
            return None
        f.write(p.stdout)
    got = parse(p.stdout) if p.returncode == 0 else None
    if got is None:
        print(f"seeds: {' '.join(cmd)} exited {p.returncode} without a complete result; see {new}", file=sys.stderr)
        return None
    os.replace(new, log)
    os.utime(log, (began, began))
    return got


def parse_mobile(out):
    m = re.search(r"success rate\s+([0-9.]+) %", out)
    return float(m.group(1)) if m else None


def parse_mclari(out):
    """(worst terrain's share of the best fixed point in %, highest fall rate) from farm-mclari-eval's table."""
    ratios, falls = [], []
    for m in re.finditer(r"^\| [a-z-]+ \| (\d+) \| [0-9.]+ \| (\d+) / (\d+) \|.*\| (\d+) % \|$", out, re.M):
        ratios.append(float(m.group(4)))
        falls.append(int(m.group(2)) / max(1, int(m.group(3))))
    return (min(ratios), max(falls)) if len(ratios) == 6 else None


def same_policy(run):
    """The policy version when RUN/best holds the final policy itself (the run's last evaluation was
    its best): the same policy_version in both manifests and every other file of RUN/best byte for
    byte in RUN/checkpoint. None otherwise."""
    best, final = os.path.join(run, "best"), os.path.join(run, "checkpoint")
    versions = [re.search(r"^policy_version: (\d+)$", read_text(os.path.join(d, "manifest.txtpb")), re.M)
                for d in (best, final)]
    if not all(versions) or versions[0].group(1) != versions[1].group(1):
        return None
    for d, _, files in os.walk(best):
        for f in files:
            rel = os.path.relpath(os.path.join(d, f), best)
            other = os.path.join(final, rel)
            if rel != "manifest.txtpb" and not (os.path.isfile(other) and
                                                 filecmp.cmp(os.path.join(d, f), other, shallow=False)):
                return None
    return versions[0].group(1)


def measure_mobile(run, args, which):
    cmd = [os.path.join(args.build, "tools", "farm-mobile-eval"), "--run-dir", run, "--episodes",
           str(args.eval_episodes)]
    if which == "best":
        cmd.append("--best")
    got = run_tool(cmd, os.path.join(run, f"eval_{which}.txt"), parse_mobile, args.remeasure)
    return math.nan if got is None else got


def measure_mclari(run, args, episodes, which):
    cmd = [os.path.join(args.build, "tools", "farm-mclari-eval"), "--config", args.config, "--checkpoint",
           os.path.join(run, "checkpoint" if which == "final" else "best"), "--best", os.path.join(ROOT, "docs", "data", "mclari_best_180s.csv"),
           "--episodes", str(episodes)]
    got = run_tool(cmd, os.path.join(run, f"eval_{which}.txt"), parse_mclari, args.remeasure)
    return (math.nan, math.nan) if got is None else got


# ---- statistics over seeds ----------------------------------------------------------------------

def iqm(xs):
    """Interquartile mean: the mean after dropping int(n/4) runs at each end (scipy's trim_mean(0.25),
    which rliable uses); with 3 seeds nothing is dropped and it is the mean."""
    xs = sorted(x for x in xs if not math.isnan(x))
    if not xs:
        return math.nan
    k = len(xs) // 4
    kept = xs[k:len(xs) - k]
    return sum(kept) / len(kept)


def median(xs):
    xs = sorted(x for x in xs if not math.isnan(x))
    if not xs:
        return math.nan
    n = len(xs)
    return xs[n // 2] if n % 2 else 0.5 * (xs[n // 2 - 1] + xs[n // 2])


def bootstrap_ci(xs, stat=iqm, reps=2000, seed=0):
    """95 % percentile bootstrap interval of stat over runs (resampling runs with replacement)."""
    xs = [x for x in xs if not math.isnan(x)]
    if len(xs) < 2:
        return math.nan, math.nan
    rng = random.Random(seed)
    vals = sorted(stat([rng.choice(xs) for _ in xs]) for _ in range(reps))
    return vals[int(0.025 * reps)], vals[int(0.975 * reps) - 1]


# ---- training -----------------------------------------------------------------------------------

def this_command():
    return "tools/seeds.py " + shlex.join(sys.argv[1:])


def train(args, text, seeds):
    learner = args.learner_bin or os.path.join(args.build, "learner", "farm-learner")
    worker = args.worker_bin or os.path.join(args.build, "worker", "farm-worker")
    for b in (learner, worker):
        if not os.access(b, os.X_OK):
            fail(f"{b} not found: build first (deploy/build.sh) or give --build")
    resume = set()
    for s in list(seeds):  # before anything starts, or command.txt is written
        run = os.path.join(args.out, f"seed{s}")
        if not os.path.exists(run):
            continue
        if not args.resume:
            fail(f"{run} exists: give another --out, --resume to continue it, or --report-only to report it")
        stop = last_stop(run)
        if stop is not None and stop != "interrupted":
            print(f"seeds: seed {s} ended on its own ({stop}): kept as it is", flush=True)
            seeds = [x for x in seeds if x != s]
        elif os.path.exists(os.path.join(run, "checkpoint", "manifest.txtpb")):
            resume.add(s)
        else:
            fail(f"{run} has no checkpoint to continue from (RUN/checkpoint/manifest.txtpb): "
                 "remove it to train that seed again")
    if not seeds:
        return []
    command_txt = os.path.join(args.out, "command.txt")
    with open(command_txt, "a" if args.resume and os.path.exists(command_txt) else "w") as f:
        f.write(this_command() + "\n")
    stopping = []
    def on_signal(signum, _frame):
        stopping.append(signum)
    before = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        failed = run_seeds(args, text, seeds, learner, worker, resume, stopping)
    finally:
        for sig, handler in before.items():
            signal.signal(sig, handler)
    if stopping:
        again = this_command() + ("" if args.resume else " --resume")
        print(f"seeds: stopped; continue with: {again}", flush=True)
        sys.exit(130)
    if failed:
        print(f"seeds: the learner failed for seed{'s' if len(failed) > 1 else ''} "
              f"{', '.join(map(str, failed))}", file=sys.stderr)
    return failed


def run_seeds(args, text, seeds, learner, worker, resume, stopping):
    """Runs the seeds, args.parallel at a time; on a signal (stopping), as the module's text says."""
    profiles = os.path.join(ROOT, "deploy", "discovery", "local.xml")
    pending, running = list(seeds), []
    free = list(range(args.parallel))  # slots: a core range and a GPU each, when asked for
    t0 = time.time()
    forwarded = killed = False
    failed = []  # seeds whose learner exited non-zero without a signal
    while pending or running:
        if stopping and not forwarded:
            forwarded = True
            left = (f"; seed{'s' if len(pending) > 1 else ''} {', '.join(map(str, pending))} not started"
                    if pending else "")
            print(f"seeds: stopping on signal {stopping[0]}: the runs in progress write their checkpoints{left}",
                  flush=True)
            pending = []
            for _, procs, _ in running:
                procs[0].send_signal(signal.SIGINT)
        if len(stopping) > 1 and not killed:  # a second signal: end now, without checkpoints
            killed = True
            print("seeds: a second signal: ending every learner and worker now (SIGKILL)", flush=True)
            for _, procs, _ in running:
                for p in procs:
                    p.kill()
        while pending and free:
            s = pending.pop(0)
            slot = free.pop(0)
            pin, env = [], dict(os.environ)
            if args.cpus_per_run:
                pin = ["taskset", "-c", f"{slot * args.cpus_per_run}-{(slot + 1) * args.cpus_per_run - 1}"]
            if args.gpus:
                env["CUDA_VISIBLE_DEVICES"] = args.gpus[slot % len(args.gpus)]
            run = os.path.join(args.out, f"seed{s}")
            cfg = os.path.join(args.out, f"seed{s}.txtpb")
            with open(cfg, "w") as f:
                f.write(re.sub(r"^seed:\s*\d+\s*$", f"seed: {s}", text, count=1, flags=re.M))
            domain = str(args.domain + s)
            common = ["--domain", domain, "--dds-profiles", profiles]
            # Logs beside the run folder: the learner moves a non-empty run folder aside.
            logs = os.path.join(args.out, "logs")
            os.makedirs(logs, exist_ok=True)
            again = ["--resume"] if s in resume else []
            mode = "a" if again else "w"  # a resumed run's logs go on after its first part's
            procs = [subprocess.Popen(pin + [learner, "--config", cfg, "--run-dir", run] + again + common,
                                      stdout=open(os.path.join(logs, f"seed{s}-learner.log"), mode),
                                      stderr=subprocess.STDOUT, env=env)]
            for w in range(args.workers):
                procs.append(subprocess.Popen(pin + [worker, "--id", f"s{s}w{w + 1}"] + common,
                                              stdout=open(os.path.join(logs, f"seed{s}-worker{w + 1}.log"), mode),
                                              stderr=subprocess.STDOUT, env=env))
            where = (f", cores {pin[2]}" if pin else "") + (
                f", GPU {env['CUDA_VISIBLE_DEVICES']}" if args.gpus else "")
            print(f"seeds: seed {s} {'resumed' if again else 'started'} (domain {domain}, {args.workers} workers{where}, "
                  f"run {run})", flush=True)
            running.append((s, procs, slot))
        time.sleep(0.5)
        for s, procs, slot in list(running):
            rc = procs[0].poll()
            if rc is None:
                continue
            for p in procs[1:]:
                if stopping:  # a stopped learner's workers wait for it to come back: stop them too
                    p.send_signal(signal.SIGINT)
                try:
                    p.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    p.terminate()
                    p.wait()
            running.remove((s, procs, slot))
            free.append(slot)
            print(f"seeds: seed {s} ended (learner exit {rc}) at {time.time() - t0:.0f} s", flush=True)
            if rc != 0 and not stopping:
                failed.append(s)
                print(f"seeds: seed {s}: the learner failed; its log: "
                      f"{os.path.join(args.out, 'logs', f'seed{s}-learner.log')}", file=sys.stderr)
    return failed


def last_stop(run):
    """The reason of the run's last stop event, None when it has none."""
    stops = run_events.read(run, "stop")
    return str(stops[-1].get("reason", "")) if stops else None


# ---- report -------------------------------------------------------------------------------------

def fmt(x, spec=".3g"):
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, spec)


def report(args, task, kind, target, seeds):
    results = []
    for s in seeds:
        run = os.path.join(args.out, f"seed{s}")
        rows = read_rows(run)
        if not os.path.isdir(run):
            print(f"seeds: seed {s}: no run folder {run}; reported as missing", file=sys.stderr)
        elif not rows:
            print(f"seeds: seed {s}: no rows in {run}/learner.csv; its figures come from its events alone",
                  file=sys.stderr)
        last = rows[-1] if rows else {}
        # The summary's figures where the run wrote one (learner.csv's last row may be seconds older).
        wall, steps = summary_value(run, "wall_s"), summary_value(run, "env_steps")
        r = dict(seed=s, wall=number(last.get("elapsed_s")) if math.isnan(wall) else wall,
                 steps=number(last.get("env_steps")) if math.isnan(steps) else steps)
        curve = measure_curve(run, "walking" if kind == "walking" else "return", target)
        r["time"] = curve["time"] if curve else math.nan
        if kind == "mobile":  # the first of the learner's evaluations (not the final one) at the goal
            r["time"] = next((t for t, v in eval_success(run, ("eval",)) if v >= MOBILE_GOAL), math.nan)
        r["same"] = same_policy(run) if kind in ("mobile", "mclari") else None
        if kind in ("return", "walking"):
            r.update(best=curve["best"] if curve else math.nan, final=curve["final"] if curve else math.nan,
                     best_ok=bool(curve and curve["best_ok"]), final_ok=bool(curve and curve["final_ok"]))
        elif kind == "mobile":
            r["best"] = measure_mobile(run, args, "best")
            r["final"] = r["best"] if r["same"] else measure_mobile(run, args, "final")
            r["best_ok"], r["final_ok"] = r["best"] >= MOBILE_GOAL, r["final"] >= MOBILE_GOAL
        else:
            r["best"], r["best_falls"] = measure_mclari(run, args, 10, "best")
            r["final"], r["final_falls"] = ((r["best"], r["best_falls"]) if r["same"] else
                                            measure_mclari(run, args, 10, "final"))
            r["best_ok"] = r["best"] >= MCLARI_GOAL and r["best_falls"] < MCLARI_FALLS
            r["final_ok"] = r["final"] >= MCLARI_GOAL and r["final_falls"] < MCLARI_FALLS
        if r["same"]:
            print(f"seeds: seed {s}: the final policy is the kept best (policy v{r['same']}, the same files): "
                  "measured once", file=sys.stderr)
        # How far the final policy ends below the kept best, in % of the best's magnitude (returns
        # may be negative, so not a ratio): -10 or lower is flagged.
        r["drop"] = 100.0 * (r["final"] - r["best"]) / abs(r["best"]) if r["best"] else math.nan
        results.append(r)

    goal, unit = {
        "return": (f"evaluation return >= {target:g}", "eval return"),
        "walking": (f"eval_tracking_lin >= {WALKING_LIN} and eval_fell < {WALKING_FELL}", "eval_tracking_lin"),
        "mobile": (f"success >= {MOBILE_GOAL:g} % over {args.eval_episodes} fresh maps", "success %"),
        "mclari": (f"every terrain >= {MCLARI_GOAL:g} % of the best fixed point, < 1 fall in 10", "worst terrain %"),
    }[kind]
    trained = "`, then `".join(line for line in read_text(os.path.join(args.out, "command.txt")).splitlines() if line)
    lines = [f"# {os.path.basename(args.config)}: {len(seeds)} seeds", "",
             f"Task `{task}`; goal: {goal}. Trained with: `{trained or 'not recorded (no command.txt)'}`"
             + (f"; measured with: `{this_command()}`" if args.report_only else ""), "",
             f"| seed | wall time [s] | env steps | goal first met at [s] | kept best ({unit}) | final ({unit}) "
             "| final - best [% of best] | best meets goal | final meets goal |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in results:
        lines.append(f"| {r['seed']} | {fmt(r['wall'], '.0f')} | {fmt(r['steps'], '.0f')} | {fmt(r['time'], '.0f')} | "
                     f"{fmt(r['best'])} | {fmt(r['final'])} | {fmt(r['drop'], '+.0f')} | "
                     f"{'yes' if r['best_ok'] else 'no'} | {'yes' if r['final_ok'] else 'no'} |")
    lines.append("")
    for name, key in (("kept best", "best"), ("final", "final"), ("time to goal [s]", "time")):
        xs = [r[key] for r in results]
        lo, hi = bootstrap_ci(xs)
        lines.append(f"- {name}: median {fmt(median(xs))}, IQM {fmt(iqm(xs))} (95 % bootstrap CI "
                     f"{fmt(lo)} .. {fmt(hi)}) over {sum(not math.isnan(x) for x in xs)} of {len(xs)} seeds")
    met = sum(r["best_ok"] for r in results)
    lines.append(f"- goal met by the kept best in {met} of {len(results)} seeds, by the final policy in "
                 f"{sum(r['final_ok'] for r in results)} of {len(results)}")
    if kind in ("mobile", "mclari"):
        same = [f"seed {r['seed']} (v{r['same']})" for r in results if r.get("same")]
        lines.append("- final policy is the kept best, measured once: " + (", ".join(same) or "none"))
    low = [r["seed"] for r in results if not math.isnan(r["drop"]) and r["drop"] <= -10]
    lines.append("- final more than 10 % below kept best: " + (", ".join(f"seed {s}" for s in low) or "none"))
    text = "\n".join(lines) + "\n"
    open(os.path.join(args.out, "seeds.md"), "w").write(text)
    with open(os.path.join(args.out, "seeds.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["seed", "wall_s", "env_steps", "goal_time_s", "best", "final", "final_minus_best_pct", "best_ok",
                    "final_ok"])
        for r in results:
            w.writerow([r["seed"], r["wall"], r["steps"], r["time"], r["best"], r["final"], r["drop"],
                        int(r["best_ok"]), int(r["final_ok"])])
    print(text, end="")
    plot(args, kind, target, seeds)
    return met


def eval_success(run, labels=("eval", "final")):
    """(elapsed s when asked, success %) of every evaluation of a mobile robot's run, its final one
    included unless labels leave it out: learner.csv has no success column."""
    return [(float(e["asked_elapsed_s"]), round(100.0 * float(e["metrics"]["success"]), 3))
            for e in evaluations(run, labels) if (e.get("metrics") or {}).get("success") is not None]


def eval_share(run):
    """(elapsed s when asked, worst terrain's share in %) of every evaluation of an mCLARI run that a
    second worker confirmed where one is asked to (the measure "share (min)": eval.best_metric /
    best_reduce)."""
    return [(float(e["asked_elapsed_s"]), round(100.0 * float(e["metrics_min"]["share"]), 3))
            for e in evaluations(run, ("eval", "final"))
            if e.get("confirmed", True) and (e.get("metrics_min") or {}).get("share") is not None]


def curve(out, s, kind):
    """(label, [(elapsed s, value)]) that the plot draws for seed s: the learner's evaluations of
    the goal's measure where it has them (success % for mobile robots), else the
    evaluation return."""
    run = os.path.join(out, f"seed{s}")
    if kind == "mobile":
        pts = eval_success(os.path.join(out, f"seed{s}"))
        if pts:
            return SUCCESS_LABEL, pts
    if kind == "mclari":
        pts = eval_share(os.path.join(out, f"seed{s}"))
        if pts:
            return SHARE_LABEL, pts
    column = "eval_tracking_lin" if kind == "walking" else "eval_return"
    if kind == "return":
        pts = eval_returns(os.path.join(out, f"seed{s}"))
        if pts:
            return column, pts
    return column + (" (learner's evaluation)" if kind in ("mobile", "mclari") else ""), [
        (number(r["elapsed_s"]), number(r[column])) for r in eval_rows(read_rows(run), column)]


def plot(args, kind, target, seeds):
    curves = {s: curve(args.out, s, kind) for s in seeds}
    with open(os.path.join(args.out, "seeds_curves.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["seed", "elapsed_s", "measure", "value"])
        for s, (label, pts) in curves.items():
            for t, v in pts:
                w.writerow([s, t, label, v])
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("seeds: no matplotlib (apt-get install python3-matplotlib); no plot", file=sys.stderr)
        return
    fig, ax = plt.subplots(figsize=(7, 4))
    labels = set()
    for s, (label, pts) in curves.items():
        if pts:
            ax.plot([t for t, _ in pts], [v for _, v in pts], marker="o", ms=3, label=f"seed {s}")
            labels.add(label)
    mobile_success = kind == "mobile" and labels == {SUCCESS_LABEL}
    goal = WALKING_LIN if kind == "walking" else MOBILE_GOAL if mobile_success else \
        MCLARI_GOAL if labels == {SHARE_LABEL} else target
    if not math.isnan(goal):
        ax.axhline(goal, color="k", ls="--", lw=1, label="goal")
    ax.set_xlabel("wall time [s]")
    # Wrapped: the worst-terrain label is longer than the figure is high.
    ax.set_ylabel(textwrap.fill(" / ".join(sorted(labels)) or "evaluation", 36))
    ax.set_title(os.path.basename(args.config))
    ax.legend()
    fig.tight_layout()
    fig.savefig(os.path.join(args.out, "seeds.png"), dpi=100)
    return fig


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("config")
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--parallel", type=int, default=3)
    ap.add_argument("--out")
    ap.add_argument("--domain", type=int, default=150, help="seed N runs on DDS domain D + N")
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--learner-bin", help="another farm-learner (e.g. a GPU build)")
    ap.add_argument("--worker-bin", help="another farm-worker")
    ap.add_argument("--cpus-per-run", type=int, default=0, help="hold each side-by-side run to this many cores")
    ap.add_argument("--gpus", type=lambda v: [g for g in v.split(",") if g], default=[],
                    help="GPU ids, one per side-by-side run (CUDA_VISIBLE_DEVICES)")
    ap.add_argument("--train-only", action="store_true", help="train, do not measure (e.g. on a host without "
                    "the evaluation programs; --report-only measures later)")
    ap.add_argument("--eval-episodes", type=int, default=100)
    ap.add_argument("--report-only", action="store_true")
    ap.add_argument("--resume", action="store_true", help="continue the runs already in --out: those stopped "
                    "from their checkpoints, seeds without a run from the start")
    ap.add_argument("--remeasure", action="store_true", help="measure each policy again even where its "
                    "measurement from the same command is newer than the policy")
    args = ap.parse_args()
    try:
        seeds = [int(s) for s in args.seeds.split(",")]
    except ValueError:
        fail(f"--seeds: expected a comma-separated list of integers, got '{args.seeds}'")
    if len(set(seeds)) != len(seeds) or min(seeds) < 0:
        fail(f"--seeds: expected distinct non-negative integers, got '{args.seeds}'")
    if args.workers < 1 or args.parallel < 1 or args.eval_episodes < 1:
        fail("--workers, --parallel and --eval-episodes must be >= 1")
    if args.cpus_per_run < 0 or args.cpus_per_run * args.parallel > (os.cpu_count() or 1):
        fail(f"--cpus-per-run {args.cpus_per_run} x --parallel {args.parallel} is more than this host's "
             f"{os.cpu_count()} cores")
    if args.train_only and args.report_only:
        fail("--train-only and --report-only exclude each other")
    if args.resume and args.report_only:
        fail("--resume and --report-only exclude each other")
    if not 0 <= args.domain + max(seeds) <= 232:
        fail(f"--domain {args.domain} + seed {max(seeds)} is outside the DDS domain ids 0..232")
    text, task, target = read_config(args.config)
    kind = goal_kind(task)
    if kind == "return" and math.isnan(target):
        fail(f"{args.config}: task '{task}' is judged on stop.target_eval_return, which the config does not set")
    args.out = args.out or os.path.join("runs", "seeds", os.path.splitext(os.path.basename(args.config))[0])
    os.makedirs(args.out, exist_ok=True)
    failed = [] if args.report_only else train(args, text, seeds)
    if args.train_only:
        sys.exit(1 if failed else 0)
    met = report(args, task, kind, target, seeds)
    sys.exit(0 if met == len(seeds) and not failed else 1)


if __name__ == "__main__":
    main()
