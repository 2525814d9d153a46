#!/usr/bin/env python3
"""The Python vector env's env steps/s next to bench_worker's worker (the C++ rollout a farm-worker
runs, policy inference included) for the same task, envs and threads, in one run.

  PYTHONPATH=build/python python3 tests/bench/bench_python_vec.py build/tests/bench_worker \
      [--task a1] [--envs 64] [--threads 2] [--seconds 5]

Prints both figures and their ratio next to the bound of 0.9; exits 1 below it.
"""
import argparse
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


def worker_rate(bench_worker, task, envs, threads, seconds):
    out = subprocess.run([bench_worker, "--task", task, "--envs", str(envs), "--threads", str(threads), "--seconds",
                          str(seconds)], check=True, capture_output=True, text=True).stdout
    m = re.search(r"^worker %d threads?: (\d+) env steps/s" % threads, out, re.M)
    if not m:
        sys.exit("bench_python_vec: no 'worker %d thread(s)' line in bench_worker's output:\n%s" % (threads, out))
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
    py, cpp = [], []
    for r in range(a.rounds):
        py.append(python_rate(a.task, a.envs, a.threads, a.seconds))
        cpp.append(worker_rate(a.bench_worker, a.task, a.envs, a.threads, a.seconds))
        print("round %d: python VecEnv %.0f env steps/s, bench_worker worker %.0f env steps/s" % (r + 1, py[-1], cpp[-1]))
    ratio = float(np.median(py) / np.median(cpp))
    print("python VecEnv: %.0f env steps/s (median)" % np.median(py))
    print("bench_worker worker: %.0f env steps/s (median)" % np.median(cpp))
    print("ratio python/worker: %.3f (bound %.2f)" % (ratio, a.bound))
    return 0 if ratio >= a.bound else 1

if __name__ == "__main__":
    sys.exit(main())
