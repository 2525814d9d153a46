#!/usr/bin/python3
"""Plots of an mCLARI characterization sweep (farm-mclari-sweep's CSV), after the mCLARI thesis §5.1-5.2:
  trajectories_<terrain>.png  the 27-panel grid: centre-of-mass paths per phase group, one line per f
  efficiency_<terrain>.png    power, speed and efficiency against frequency, one line per group
usage: /usr/bin/python3 tools/mclari_plots.py SWEEP_DIR (Debian python3-matplotlib)"""
import csv
import os
import sys
from collections import defaultdict

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    d = sys.argv[1]
    traj = defaultdict(lambda: defaultdict(list))  # (terrain) -> (group, f) -> [(x, y)]
    names = {}
    with open(os.path.join(d, "trajectories.csv")) as f:
        for r in csv.DictReader(f):
            t = int(r["terrain"])
            names[t] = r["terrain_name"]
            traj[t][(int(r["group"]), int(r["frequency_hz"]))].append((float(r["x_mm"]), float(r["y_mm"])))
    summary = defaultdict(lambda: defaultdict(list))  # terrain -> group -> [(f, P, v, eta)]
    group_names = {}
    with open(os.path.join(d, "summary.csv")) as f:
        for r in csv.DictReader(f):
            g = int(r["group"])
            group_names[g] = r["group_name"]
            summary[int(r["terrain"])][g].append(
                (int(r["frequency_hz"]), float(r["power_w"]), float(r["speed_mm_s"]), float(r["efficiency"])))

    for t, runs in sorted(traj.items()):
        groups = sorted({g for g, _ in runs})
        freqs = sorted({fr for _, fr in runs})
        cols = 9 if len(groups) > 9 else len(groups)
        rows = (len(groups) + cols - 1) // cols
        fig, axes = plt.subplots(rows, cols, figsize=(2.4 * cols, 2.4 * rows), squeeze=False)
        cmap = plt.get_cmap("viridis", len(freqs))
        for i, g in enumerate(groups):
            ax = axes[i // cols][i % cols]
            for j, fr in enumerate(freqs):
                p = runs.get((g, fr))
                if p:
                    ax.plot([q[0] for q in p], [q[1] for q in p], color=cmap(j), lw=1, label=f"{fr} Hz")
            ax.set_title(group_names.get(g, str(g)), fontsize=8)
            ax.tick_params(labelsize=6)
            ax.set_aspect("equal", adjustable="datalim")
        for k in range(len(groups), rows * cols):
            axes[k // cols][k % cols].axis("off")
        handles, labels = axes[0][0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="lower center", ncol=len(freqs), fontsize=8)
        fig.suptitle(f"centre-of-mass paths (mm), {names[t]}")
        fig.tight_layout(rect=(0, 0.04, 1, 0.97))
        fig.savefig(os.path.join(d, f"trajectories_{names[t]}.png"), dpi=80)
        plt.close(fig)

    for t, by_group in sorted(summary.items()):
        fig, axes = plt.subplots(1, 3, figsize=(16, 5))
        for g, pts in sorted(by_group.items()):
            pts.sort()
            fs = [p[0] for p in pts]
            for ax, k in zip(axes, (1, 2, 3)):
                ax.plot(fs, [p[k] for p in pts], marker=".", lw=0.8, label=group_names.get(g, str(g)))
        for ax, label in zip(axes, ("sum of mean |P| [W]", "mean speed [mm/s]", "efficiency")):
            ax.set_xlabel("frequency [Hz]")
            ax.set_ylabel(label)
        axes[0].set_yscale("log")
        axes[2].legend(fontsize=6, ncol=2)
        fig.suptitle(f"power, speed and efficiency against frequency per phase group, {names.get(t, t)}")
        fig.tight_layout()
        fig.savefig(os.path.join(d, f"efficiency_{names.get(t, t)}.png"), dpi=80)
        plt.close(fig)
    print(f"plots written under {d}")


if __name__ == "__main__":
    main()
