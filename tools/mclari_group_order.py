#!/usr/bin/python3
"""An order for an mCLARI config's `groups` list, from a characterization sweep's summary.csv.

a1 picks a group by its index in `groups`, and SAC's actor follows the critic's slope along a1,
so it moves to a neighbouring index only when that pays more. If a terrain's efficiency along the
list has a valley between the gait the policy holds and a better one, the policy stays where it is
(docs/record/mclari.md step 11). This prints, for the given groups, every terrain's efficiency along the
list at that terrain's best frequency, and the orders in which a climb from any index to a better
neighbour ends within 10 % of that terrain's best.
usage: python3 tools/mclari_group_order.py SWEEP_DIR 5,11,15,19,20,23 [--at-most 10]"""
import csv
import itertools
import os
import sys


def climb_ends_near_best(values, within=0.9):
    best = max(values)
    for start in range(len(values)):
        i = start
        while True:
            up = max((j for j in (i - 1, i + 1) if 0 <= j < len(values)), key=lambda j: values[j])
            if values[up] <= values[i]:
                break
            i = up
        if values[i] < within * best:
            return False
    return True


def main():
    args = sys.argv[1:]
    at_most = 10
    if "--at-most" in args:
        k = args.index("--at-most")
        at_most = int(args[k + 1])
        del args[k:k + 2]
    if len(args) != 2:
        sys.exit(__doc__)
    try:
        groups = [int(g) for g in args[1].split(",")]
    except ValueError:
        sys.exit(f"groups must be comma-separated integers, got '{args[1]}'")
    eff, names = {}, {}
    with open(os.path.join(args[0], "summary.csv")) as f:
        for r in csv.DictReader(f):
            t = int(r["terrain"])
            names[t] = r["terrain_name"]
            eff[(t, int(r["group"]), int(r["frequency_hz"]))] = float(r["efficiency"])
    freqs = sorted({fr for _, _, fr in eff})
    missing = [g for g in groups if not any((t, g, fr) in eff for t in names for fr in freqs)]
    if missing:
        sys.exit(f"groups {missing} are not in {args[0]}/summary.csv")
    # Each terrain at the frequency where the given groups reach their best.
    at = {t: max(freqs, key=lambda fr: max(eff.get((t, g, fr), 0.0) for g in groups)) for t in names}

    def row(t, order):
        return [eff.get((t, g, at[t]), 0.0) for g in order]

    def show(order):
        print("groups " + " ".join(f"{g:>5d}" for g in order))
        for t in sorted(names):
            v = row(t, order)
            mark = "" if climb_ends_near_best(v) else "   <- a climb can end below 90 %"
            print(f"{names[t]:>12s} {at[t]:>3d} Hz " + " ".join(f"{100 * x / max(v):4.0f}%" for x in v) + mark)

    print(f"efficiency along the list, % of the best of these groups ({args[0]}/summary.csv):")
    show(groups)
    good = [p for p in itertools.permutations(groups)
            if all(climb_ends_near_best(row(t, p)) for t in names)]
    print(f"\n{len(good)} of {len(list(itertools.permutations(groups)))} orders let every climb end "
          f"within 10 % of the terrain's best" + (":" if good else "."))
    for p in good[:at_most]:
        print("  groups: [" + ", ".join(str(g) for g in p) + "]")


if __name__ == "__main__":
    main()
