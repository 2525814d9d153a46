#!/usr/bin/env python3
"""Checks a model farm-export wrote against the worker's own actions: onnx.checker accepts it, its
metadata names the task, sizes and algorithm, and OpenCV's DNN module (cv2.dnn) computes from the
recorded observations the actions the worker's Eigen policy took (farm-export --record's CSV).

  check_onnx_export.py MODEL.onnx RECORD.csv ALGORITHM [TOLERANCE [MIN_DISTINCT]]

SAC, PPO: max |action_onnx - action_eigen| <= TOLERANCE (default 1e-5), with at least a tenth of
the rows inside (-1, 1) (not clipped). DQN: the same argmax action on every row, at least
MIN_DISTINCT (default 2) different actions among them, and max |q_onnx - q_eigen| <= TOLERANCE. Exits 1 with the reason otherwise.
"""
import sys

import cv2
import numpy as np
import onnx


def fail(msg):
    print(f"FAIL: {msg}")
    sys.exit(1)


def main():
    model_path, record_path, algorithm = sys.argv[1:4]
    tol = float(sys.argv[4]) if len(sys.argv) > 4 else 1e-5
    min_distinct = int(sys.argv[5]) if len(sys.argv) > 5 else 2

    model = onnx.load(model_path)
    onnx.checker.check_model(model, full_check=True)  # raises onnx.checker.ValidationError
    meta = {p.key: p.value for p in model.metadata_props}
    for key in ("task", "observation_size", "action_size", "algorithm", "policy_version", "experiment_id",
                "action_head", "observation_normalizer"):
        if key not in meta:
            fail(f"metadata has no '{key}': {sorted(meta)}")
    if meta["algorithm"] != algorithm:
        fail(f"metadata algorithm '{meta['algorithm']}', expected '{algorithm}'")
    if [i.name for i in model.graph.input] != ["obs"]:
        fail(f"graph inputs {[i.name for i in model.graph.input]}, expected ['obs']")

    with open(record_path) as f:
        header = f.readline().strip().split(",")
    data = np.loadtxt(record_path, delimiter=",", skiprows=1, dtype=np.float64, ndmin=2)
    obs_cols = [i for i, h in enumerate(header) if h.startswith("obs_")]
    act_cols = [i for i, h in enumerate(header) if h.startswith("action_")]
    q_cols = [i for i, h in enumerate(header) if h.startswith("q_")]
    obs = data[:, obs_cols].astype(np.float32)  # the CSV holds each float in 9 digits: exact
    act = data[:, act_cols].astype(np.float32)
    if len(obs_cols) != int(meta["observation_size"]):
        fail(f"{len(obs_cols)} observation columns, metadata observation_size {meta['observation_size']}")
    if len(act_cols) != int(meta["action_size"]):
        fail(f"{len(act_cols)} action columns, metadata action_size {meta['action_size']}")
    if not np.isfinite(obs).all():
        fail("recorded observations are not all finite")

    net = cv2.dnn.readNetFromONNX(model_path)
    net.setInput(obs, "obs")
    n = len(obs)
    if algorithm == "dqn":
        onnx_act, onnx_q = net.forward(["action", "q_values"])
        q = data[:, q_cols].astype(np.float32)
        if onnx_q.shape != q.shape:
            fail(f"q_values shape {onnx_q.shape}, expected {q.shape}")
        if onnx_act.shape != (n, 1):
            fail(f"action shape {onnx_act.shape}, expected {(n, 1)}")
        q_diff = float(np.abs(onnx_q - q).max())
        same = int((onnx_act.astype(np.int64) == act.astype(np.int64)).sum())
        distinct = len(np.unique(act))
        print(f"{algorithm}: {n} observations of task {meta['task']}, argmax identical on {same} of {n}, "
              f"{distinct} distinct actions; max |q_onnx - q_eigen| = {q_diff:.3g} (limit {tol:g}), "
              f"q spread {float(q.std()):.3g}")
        if same != n:
            fail(f"argmax differs on {n - same} rows")
        if not q_diff <= tol:
            fail(f"Q values differ by {q_diff:.3g} > {tol:g}")
        if distinct < min_distinct:
            fail(f"the recorded policy took {distinct} different actions, expected at least {min_distinct}")
    else:
        (onnx_act,) = net.forward(["action"])
        if onnx_act.shape != act.shape:
            fail(f"action shape {onnx_act.shape}, expected {act.shape}")
        diff = float(np.abs(onnx_act - act).max())
        # Rows whose every action lies inside (-1, 1): there the network's output itself is compared,
        # not a bound both sides clip to.
        inside = int((np.abs(act) < 1).all(axis=1).sum())
        print(f"{algorithm}: {n} observations of task {meta['task']}, max |action_onnx - action_eigen| = "
              f"{diff:.3g} (limit {tol:g}); actions in [{float(act.min()):.3f}, {float(act.max()):.3f}], "
              f"std {float(act.std()):.3g}, {inside} rows inside (-1, 1); normalizer: {meta['observation_normalizer']}")
        if not diff <= tol:
            fail(f"actions differ by {diff:.3g} > {tol:g}")
        if not (np.abs(act) <= 1).all():
            fail("recorded actions leave [-1, 1]")
        if float(act.std()) < 1e-3:
            fail("the recorded actions are (nearly) constant: the comparison would be vacuous")
        if inside < n // 10:
            fail(f"only {inside} of {n} rows have all actions inside (-1, 1): the comparison would be mostly of clipped bounds")


if __name__ == "__main__":
    main()
