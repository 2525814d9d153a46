#!/usr/bin/python3
"""Plots the learner's evaluations of the runs in a tests/bench/bench_seeds.sh output (a results
page's data file): each "seed N, W workers: v@t v@t ..." line is one run's curve, the value of the
goal's metric when each evaluation was asked against the run's wall time.

  tools/plot_evaluations.py FILE --out PNG --panel 'TITLE=REGEX' [--panel ...] [--goal 'TITLE=V']
                            [--ylabel 'TITLE=LABEL'] [--until REGEX]

A run belongs to the section it appears in: the last line before it that is a "## NAME" heading
or a line "NAME:" of its own. Each --panel draws the runs whose section matches REGEX (Python re,
searched), labelled by seed; --goal draws the goal's value as a dashed line; --until stops reading
at the first line that matches. Runs with /usr/bin/python3 (Debian's matplotlib)."""
import argparse
import re
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

RUN = re.compile(r"^seed (\d+), (\d+) workers?: (.*)$")
SECTION = re.compile(r"^(?:## (.+)|([A-Za-z][\w .-]*):)\s*$")


def named(pairs, what):
    out = {}
    for p in pairs:
        title, sep, value = p.partition("=")
        if not sep:
            sys.exit(f"plot_evaluations: {what} '{p}': expected TITLE=VALUE")
        out[title] = value
    return out


def read_runs(path, until):
    runs, section = [], ""
    try:
        lines = open(path).read().splitlines()
    except OSError as e:
        sys.exit(f"plot_evaluations: cannot read {path}: {e.strerror}")
    for line in lines:
        if until and re.search(until, line):
            break
        m = SECTION.match(line)
        if m:
            section = m.group(1) or m.group(2)
            continue
        m = RUN.match(line)
        if not m:
            continue
        points = []
        for item in m.group(3).split():
            v, at, t = item.partition("@")
            try:
                points.append((float(t), float(v)))
            except ValueError:
                sys.exit(f"plot_evaluations: {path}: '{item}' in \"{line[:60]}\" is not VALUE@SECONDS")
        runs.append(dict(section=section, seed=int(m.group(1)), points=points))
    return runs


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("file")
    ap.add_argument("--out", required=True)
    ap.add_argument("--panel", action="append", required=True)
    ap.add_argument("--goal", action="append", default=[])
    ap.add_argument("--ylabel", action="append", default=[])
    ap.add_argument("--until")
    a = ap.parse_args()
    panels, goals, ylabels = named(a.panel, "--panel"), named(a.goal, "--goal"), named(a.ylabel, "--ylabel")
    runs = read_runs(a.file, a.until)
    fig, axes = plt.subplots(1, len(panels), figsize=(5.5 * len(panels), 3.8), squeeze=False)
    for ax, (title, regex) in zip(axes[0], panels.items()):
        chosen = [r for r in runs if re.search(regex, r["section"])]
        if not chosen:
            sys.exit(f"plot_evaluations: panel '{title}': no run in a section matching '{regex}' "
                     f"(sections: {sorted(set(r['section'] for r in runs))})")
        for r in chosen:
            ax.plot([t for t, _ in r["points"]], [v for _, v in r["points"]], marker=".", label=f"seed {r['seed']}")
        if title in goals:
            ax.axhline(float(goals[title]), color="k", linestyle="--", linewidth=1, label="goal")
        ax.set_title(title)
        ax.set_xlabel("wall time [s]")
        ax.set_ylabel(ylabels.get(title, "evaluation"))
        ax.legend(fontsize=7, ncol=2)
        print(f"plot_evaluations: {title}: {len(chosen)} runs")
    fig.tight_layout()
    fig.savefig(a.out, dpi=100)
    print(f"plot_evaluations: wrote {a.out}")


if __name__ == "__main__":
    main()
