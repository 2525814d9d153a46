"""Run folders and trained policies.

A run folder (``--run-dir``, or ``run_root/experiment_id``) holds ``learner.csv`` (one row per
progress record), ``events.jsonl`` (one JSON object per event: docs/guides/monitoring.md),
``summary.txt`` and the ``checkpoint/`` and ``best/`` folders, each with a ``manifest.txtpb`` and
the policy in the workers' layout (``policy.bin``).
"""
import json
import os

import numpy as np

from . import _farm


class Policy:
    """A trained policy as the workers compute it in evaluations: the deterministic action (the
    mode: tanh of the mean, the greedy action of a Q head), from a NumPy observation of shape
    ``(obs_dim,)`` or ``(rows, obs_dim)``."""

    def __init__(self, path):
        self._core = _farm.PolicyCore(os.fspath(path))
        self.obs_dim = self._core.obs_dim
        self.act_dim = self._core.act_dim
        self.num_actions = self._core.num_actions
        self.version = self._core.version

    def __call__(self, obs):
        return self._core.act(np.asarray(obs, dtype=np.float32))

    def params(self):
        """The layout and numbers: sizes, activation, head, normalizer and the flat parameters
        (per layer the weight matrix, row-major [out x in], then the bias)."""
        return self._core.params()

    def __repr__(self):
        return "Policy(%s, version %d)" % (self._core.describe(), self.version)


def load_policy(path):
    """The policy of ``RUN/best``, ``RUN/checkpoint``, or a ``policy.bin`` file."""
    return Policy(path)


class Run:
    """A run folder, read when asked."""

    def __init__(self, folder):
        self.folder = os.fspath(folder)
        if not os.path.isdir(self.folder):
            raise FileNotFoundError("no run folder %s" % self.folder)

    def _path(self, *parts):
        return os.path.join(self.folder, *parts)

    def csv(self):
        """learner.csv as a pandas DataFrame."""
        import pandas

        return pandas.read_csv(self._path("learner.csv"))

    def events(self, kind=None):
        """The events of events.jsonl (dicts), those of one kind (``event``) if given."""
        out = []
        with open(self._path("events.jsonl")) as f:
            for line in f:
                if line.strip():
                    e = json.loads(line)
                    if kind is None or e.get("event") == kind:
                        out.append(e)
        return out

    def summary(self):
        """The summary event of the run (the figures of summary.txt), or None before the run ended."""
        found = self.events("summary")
        return found[-1] if found else None

    def manifest(self, which="checkpoint"):
        """The manifest of ``checkpoint`` or ``best`` as a dict (field names as in the schema)."""
        return json.loads(_farm.manifest_json(self._path(which, "manifest.txtpb")))

    def policy(self, which="best"):
        """The policy of ``best`` or ``checkpoint`` (``load_policy``)."""
        return Policy(self._path(which))

    def __repr__(self):
        return "Run(%r)" % self.folder


def read_run(folder):
    """A Run of the folder; raises FileNotFoundError naming it when it is not there."""
    return Run(folder)
