"""Vector environments of the farm's tasks, in Gymnasium's ``VectorEnv`` conventions.

Autoreset mode: same step (Gymnasium's ``AutoresetMode.SAME_STEP``). An env whose episode ends in
``step`` is reset within that step: the observation returned for it is the first of its next
episode, its true last observation is ``infos["final_obs"][i]`` where ``infos["_final_obs"][i]``
is True, and its episode's return and length are ``infos["episode"]["r"][i]`` and ``["l"][i]``
(mask ``infos["_episode"]``). ``rewards``, ``terminations`` and ``truncations`` are those of the
step that ended it.

The observation, reward and flag arrays returned are NumPy views of the C++ buffers (no copy per
step): the next ``step`` or ``reset`` overwrites them. Copy what you keep (``obs.copy()``). The GIL
is released while the environments step, so other Python threads run meanwhile.
"""
import os

import numpy as np

from . import _farm
from .spaces import Box, Discrete


class VecEnv:
    """``num_envs`` environments of one task, stepped by ``threads`` C++ threads."""

    metadata = {"autoreset_mode": "same_step"}

    def __init__(self, config, num_envs, threads=1, seed=0):
        self._core = _farm.VecEnvCore(os.fspath(config), int(num_envs), int(threads), int(seed))
        self.num_envs = self._core.num_envs
        self.threads = self._core.threads
        self.metric_names = list(self._core.metric_names)
        obs_dim = self._core.obs_dim
        self.single_observation_space = Box(-np.inf, np.inf, (obs_dim,), np.float32)
        if self._core.num_actions > 0:
            self.single_action_space = Discrete(self._core.num_actions)
            self.action_shape = (self.num_envs,)
        else:
            self.single_action_space = Box(-1.0, 1.0, (self._core.act_dim,), np.float32)
            self.action_shape = (self.num_envs, self._core.act_dim)
        self._seed = int(seed)

    def reset(self, seed=None, options=None):
        """Starts a new episode in every env; ``seed`` restarts the envs' seed generators (the same
        seed gives the same observations). Returns ``(obs, infos)``."""
        self._core.reset(None if seed is None else int(seed))
        return self._core.obs(), {}

    def step(self, actions):
        """Steps every env. ``actions``: float32 of shape ``(num_envs, act_dim)`` in [-1, 1]
        (the task scales them), or integers of shape ``(num_envs,)`` for a task of discrete
        actions; a ValueError names the shape expected otherwise. Returns ``(obs, rewards,
        terminations, truncations, infos)``."""
        if not isinstance(actions, np.ndarray):
            raise ValueError("actions: expected a NumPy array of shape %s, got %s" % (self.action_shape,
                                                                                    type(actions).__name__))
        self._core.step(actions)
        return (self._core.obs(), self._core.rewards(), self._core.terminated(), self._core.truncated(),
                self._infos())

    def _infos(self):
        ended = self._core.ended()
        if ended is None:
            return {}
        n = self.num_envs
        mask = np.zeros(n, dtype=bool)
        mask[ended["env"]] = True
        final_obs = np.zeros((n, self._core.obs_dim), dtype=np.float32)
        final_obs[ended["env"]] = ended["final_obs"]
        r = np.zeros(n, dtype=np.float32)
        r[ended["env"]] = ended["episode_return"]
        l = np.zeros(n, dtype=np.int32)
        l[ended["env"]] = ended["episode_length"]
        infos = {"final_obs": final_obs, "_final_obs": mask, "episode": {"r": r, "l": l}, "_episode": mask}
        if self.metric_names:
            metrics = np.zeros((n, len(self.metric_names)), dtype=np.float32)
            metrics[ended["env"]] = ended["metrics"]
            infos["metrics"] = {name: metrics[:, k] for k, name in enumerate(self.metric_names)}
            infos["_metrics"] = mask
        return infos

    def close(self):
        self._core = None

    def __repr__(self):
        return "VecEnv(%d envs, %d threads, obs %s, actions %s)" % (
            self.num_envs, self.threads, self.single_observation_space, self.single_action_space)


def make_vec(config, num_envs, threads=1, seed=0):
    """A VecEnv of the task a config names: a config file's path (its ``task`` section; a task of
    terms reads its model from the config's folder), or a task name (``farm.task_names()``) with
    that task's defaults."""
    return VecEnv(config, num_envs, threads, seed)
