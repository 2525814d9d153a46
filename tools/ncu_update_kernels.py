#!/usr/bin/env python3
"""Kernel time of one update from an Nsight Compute CSV (ncu --metrics gpu__time_duration.sum --csv
--log-file F, over consecutive updates): the first run of kernels that repeats, summed by kernel
name, largest first.
    tools/ncu_update_kernels.py F [TOP]"""
import collections
import csv
import re
import sys

rows = list(csv.DictReader(l for l in open(sys.argv[1]) if not l.startswith("==")))
names = [r["Kernel Name"] for r in rows]
period = next(p for p in range(20, len(names) - 20) if names[p:p + 20] == names[:20])
total, count = collections.Counter(), collections.Counter()
for r in rows[:period]:
    name = re.sub(r"^void ", "", re.sub(r"\(T1.*|\(cublas.*", "", r["Kernel Name"]))[:110]
    total[name] += float(r["Metric Value"].replace(",", "")) / 1000
    count[name] += 1
print(f"one update: {period} kernels, {sum(total.values()):.1f} us")
for name, us in total.most_common(int(sys.argv[2]) if len(sys.argv) > 2 else 12):
    print(f"{us:8.1f} us {count[name]:4d}x  {name}")
