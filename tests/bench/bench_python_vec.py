#!/usr/bin/env python3
"""The Python vector env's env steps/s next to the same envs stepped from C++ without Python
(bench_worker --env-only: the farm::VecEnv that farm.make_vec steps, driven as its pool drives it,
no policy in either loop) for the same task, envs and threads, in one run.

  PYTHONPATH=build/python python3 tests/bench/bench_python_vec.py build/tests/bench_worker \
      [--task a1] [--envs 64] [--threads 2] [--seconds 5]

Prints both figures and their ratio next to the bound of 0.9; exits 1 below it.
"""
import argparse
import os
import re
import subprocess
import sys
import time

import numpy as np

import farm


def python_rate(task, envs, threads, seconds):
    # Views (copy=False), as the C++ rollout reads its observations in place and as the guide's
    # figures were measured; the default copy per step costs a little more.
    env = farm.make_vec(task, envs, threads=threads, seed=1, copy=False)
    env.reset(seed=1)
    rng = np.random.default_rng(1)
    if isinstance(env.single_action_space, farm.Discrete):
        actions = [rng.integers(env.single_action_space.n, size=envs) for _ in range(64)]
    else:
        # Actions as a policy with noise of std 0.5 gives them (bench_worker's visited states).
        actions = [np.clip(rng.normal(0, 0.5, env.action_shape), -1, 1).astype(np.float32) for _ in range(64)]
    for k in range(20):  # warm up
        env.step(actions[k % 64])
    steps, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for a in actions[:16]:
            env.step(a)
        steps += 16 * envs
    return steps / (time.perf_counter() - t0)


def env_only_rate(bench_worker, task, envs, threads, seconds):
    out = subprocess.run([bench_worker, "--task", task, "--envs", str(envs), "--threads", str(threads), "--seconds",
                          str(seconds), "--env-only"], check=True, capture_output=True, text=True).stdout
    m = re.search(r"^env-only VecEnv %d thread\(s\): (\d+) env steps/s" % threads, out, re.M)
    if not m:
        sys.exit("bench_python_vec: no 'env-only VecEnv %d thread(s)' line in bench_worker's output:\n%s"
                 % (threads, out))
    return float(m.group(1))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bench_worker")
    ap.add_argument("--task", default="a1")
    ap.add_argument("--envs", type=int, default=64)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--bound", type=float, default=0.9)
    ap.add_argument("--rounds", type=int, default=3, help="alternating measurements of each; medians compared")
    a = ap.parse_args()
    print("task %s, %d envs, %d threads, %.1f s per figure, %d rounds" % (a.task, a.envs, a.threads, a.seconds,
                                                                          a.rounds))
    # Whatever else runs on the machine takes from both loops: the load says how much there was.
    print("load average at the start: %.2f %.2f %.2f" % os.getloadavg())
    py, cpp = [], []
    for r in range(a.rounds):
        py.append(python_rate(a.task, a.envs, a.threads, a.seconds))
        cpp.append(env_only_rate(a.bench_worker, a.task, a.envs, a.threads, a.seconds))
        print("round %d: python VecEnv %.0f env steps/s, C++ env-only loop %.0f env steps/s, ratio %.3f"
              % (r + 1, py[-1], cpp[-1], py[-1] / cpp[-1]))
    print("load average at the end: %.2f %.2f %.2f" % os.getloadavg())
    ratio = float(np.median(py) / np.median(cpp))
    print("python VecEnv: %.0f env steps/s (median)" % np.median(py))
    print("C++ env-only loop: %.0f env steps/s (median)" % np.median(cpp))
    print("ratio python/C++: %.3f (bound %.2f)" % (ratio, a.bound))
    # Each round measures both loops back to back: the median of their ratios is less moved by load
    # that comes and goes than the ratio of the medians.
    print("median of the rounds' ratios: %.3f" % float(np.median(np.array(py) / np.array(cpp))))
    return 0 if ratio >= a.bound else 1

if __name__ == "__main__":
    sys.exit(main())
