"""Shared fixtures: the checkpoints of tests/data with the policy files farm-policy-file writes,
and a run folder around the SAC one."""
import os
import shutil
import subprocess

import pytest

SOURCE = os.environ.get("FARM_SOURCE_DIR", os.path.join(os.path.dirname(__file__), "..", ".."))


@pytest.fixture(scope="session")
def checkpoints(tmp_path_factory):
    """The SAC and PPO checkpoints of tests/data with their policy files written by farm-policy-file."""
    prog = os.environ.get("FARM_POLICY_FILE")
    if not prog:
        pytest.skip("FARM_POLICY_FILE not set")
    out = {}
    for algo in ("sac", "ppo"):
        dst = tmp_path_factory.mktemp(algo) / "checkpoint"
        shutil.copytree(os.path.join(SOURCE, "tests", "data", "checkpoint_v1", algo, "checkpoint"), dst)
        subprocess.run([prog, str(dst)], check=True, capture_output=True)
        out[algo] = dst
    return out



@pytest.fixture(scope="session")
def run_folder(checkpoints, tmp_path_factory):
    """A run folder: the SAC checkpoint, a learner.csv and an events.jsonl with a start and a summary."""
    run = tmp_path_factory.mktemp("run") / "pendulum_sac"
    run.mkdir()
    shutil.copytree(checkpoints["sac"], run / "checkpoint")
    (run / "learner.csv").write_text("elapsed_s,env_steps,updates\n1.0,100,0\n2.0,300,40\n")
    (run / "events.jsonl").write_text('{"event":"start","elapsed_s":0.0}\n'
                                      '{"event":"summary","elapsed_s":2.0,"batches_lost":0}\n')
    return run
