"""One environment of a farm task: a Gymnasium ``Env``, and the ids ``farm/TASK`` registered.

``Env`` subclasses ``gymnasium.Env`` where gymnasium imports, and a small base with the same
attributes and methods where it does not. Its episodes are those of env 0 of a one-env
``farm.make_vec``: ``Env(task).reset(seed=s)`` and ``make_vec(task, 1).reset(seed=s)`` start the
same episode, and so does env ``i`` of ``make_vec(task, n).reset(seed=[..., s, ...])``.

The step that ends an episode returns its last observation and an info with the episode's
``episode_return``, ``episode_length`` and task ``metrics``; the next ``reset()`` starts the next
episode (with no seed, the one the C++ env already started, so that the episodes follow the same
seeds as a vector env's).

Where gymnasium imports, ``import farm`` registers ``farm/TASK`` for every task of
``farm.task_names()``: ``gymnasium.make("farm/pendulum")`` makes an ``Env``,
``gymnasium.make_vec("farm/pendulum", num_envs=8)`` a ``VecEnv``; ``config=PATH`` makes either of a
config file (``farm/terms`` needs one).
"""
import os

import numpy as np

from . import _farm
from .spaces import Box, Discrete
from .vector import ClosedEnvironmentError, to_actions

try:  # pragma: no cover - taken only where gymnasium is installed
    import gymnasium
    from gymnasium import Env as _Base
except ImportError:
    gymnasium = None

    class _Base:
        """The attributes and methods of ``gymnasium.Env`` (Gymnasium 1.x), for where gymnasium does
        not import."""

        metadata = {"render_modes": []}
        render_mode = None
        spec = None
        observation_space = None
        action_space = None
        _np_random = None
        _np_random_seed = None

        def reset(self, *, seed=None, options=None):
            if seed is not None:
                self._np_random, self._np_random_seed = np.random.default_rng(seed), seed

        def step(self, action):
            raise NotImplementedError

        def render(self):
            raise NotImplementedError

        def close(self):
            pass

        @property
        def np_random_seed(self):
            if self._np_random_seed is None:
                self._np_random_seed = int(np.random.SeedSequence().entropy)
                self._np_random = np.random.default_rng(self._np_random_seed)
            return self._np_random_seed

        @property
        def np_random(self):
            if self._np_random is None:
                self.np_random_seed  # noqa: B018 - makes both
            return self._np_random

        @np_random.setter
        def np_random(self, value):
            self._np_random, self._np_random_seed = value, -1

        @property
        def unwrapped(self):
            return self

        def has_wrapper_attr(self, name):
            return hasattr(self, name)

        def get_wrapper_attr(self, name):
            return getattr(self, name)

        def set_wrapper_attr(self, name, value, *, force=True):
            setattr(self, name, value)
            return True

        def __str__(self):
            if self.spec is None:
                return "<%s instance>" % type(self).__name__
            return "<%s<%s>>" % (type(self).__name__, self.spec.id)

        def __enter__(self):
            return self

        def __exit__(self, *args):
            self.close()
            return False


class Env(_Base):
    """One environment of the task ``config`` names (a task name or a config file, as
    ``farm.make_vec``)."""

    metadata = {"render_modes": []}

    def __init__(self, config, seed=0, render_mode=None):
        self._core = None
        if render_mode is not None:
            raise ValueError("render_mode: the farm's envs render no frames in Python (None), got %r; "
                             "farm-play records videos of a trained policy" % (render_mode,))
        self.config = os.fspath(config)
        self._core = _farm.VecEnvCore(self.config, 1, 1, int(seed))
        self._args = (self.config, int(seed))
        self.metric_names = list(self._core.metric_names)
        self.observation_space = Box(-np.inf, np.inf, (self._core.obs_dim,), np.float32)
        if self._core.num_actions > 0:
            self.action_space = Discrete(self._core.num_actions)
        else:
            self.action_space = Box(-1.0, 1.0, (self._core.act_dim,), np.float32)
        self.render_mode = None
        self._started = False  # an episode is under way that reset() without a seed may hand out
        self._core.reset(None)
        self._started = True

    def _live_core(self, what):
        if self._core is None:
            raise ClosedEnvironmentError("%s of a closed %s: make a new one" % (what, type(self).__name__))
        return self._core

    def reset(self, *, seed=None, options=None):
        """Starts an episode; ``seed`` (a non-negative int) restarts the seed generator first.
        Returns ``(obs, info)``."""
        core = self._live_core("reset")
        if options:
            raise ValueError("reset: the farm's envs take no options, got %s" % sorted(options))
        if seed is not None:
            if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
                raise ValueError("seed: expected a non-negative int or None, got %r" % (seed,))
            self._np_random, self._np_random_seed = np.random.default_rng(int(seed)), int(seed)
            core.reset(int(seed))
        elif not self._started:
            core.reset(None)
        self._started = False
        return core.obs()[0].copy(), {}

    def step(self, action):
        """One step. ``action``: of shape ``(act_dim,)`` (or a number for a one-dimensional one) in
        [-1, 1], or an int for a task of discrete actions; converted as ``farm.VecEnv`` converts.
        Returns ``(obs, reward, terminated, truncated, info)``."""
        core = self._live_core("step")
        if isinstance(self.action_space, Discrete):
            a = action.detach().cpu().numpy() if hasattr(action, "detach") else action
            a = np.asarray(a)
            if a.shape != () or a.dtype.kind not in "iu":
                raise ValueError("action: expected an integer in [0, %d), got shape %s of %s"
                                 % (self.action_space.n, a.shape, a.dtype))
            batch = to_actions(a.reshape(1), self.action_space, 1)
        else:
            a = action.detach().cpu().numpy() if hasattr(action, "detach") else action
            try:
                a = np.asarray(a)
            except (TypeError, ValueError):
                a = np.asarray(None)
            dim = self.action_space.shape[0]
            if a.shape == () and dim == 1:
                a = a.reshape(1)
            if a.shape != (dim,) or a.dtype.kind not in "fiu":
                raise ValueError("action: expected shape (%d,) of real numbers%s, got shape %s of %s"
                                 % (dim, " or a number" if dim == 1 else "", a.shape, a.dtype))
            batch = to_actions(a.reshape(1, dim), self.action_space, 1)
        core.step(batch)
        reward = float(core.rewards()[0])
        terminated, truncated = bool(core.terminated()[0]), bool(core.truncated()[0])
        ended = core.ended()
        if ended is None:
            return core.obs()[0].copy(), reward, terminated, truncated, {}
        info = {"episode_return": float(ended["episode_return"][0]), "episode_length": int(ended["episode_length"][0])}
        if self.metric_names:
            info["metrics"] = {name: float(ended["metrics"][0][j]) for j, name in enumerate(self.metric_names)}
        self._started = True  # the C++ env already started the next episode
        return ended["final_obs"][0].copy(), reward, terminated, truncated, info

    def render(self):
        """None: the envs render no frames in Python."""
        return None

    def close(self):
        """Ends the C++ env; closing again does nothing, ``step`` after it raises
        ClosedEnvironmentError."""
        self._core = None

    def __getstate__(self):
        raise TypeError("%s cannot be pickled: its environment's state lives in C++. To have one in another "
                        "process, make it there: farm.Env(%r, seed=%d)" % ((type(self).__name__,) + self._args))

    def __repr__(self):
        return "Env(%s, obs %s, actions %s)" % (self.config, self.observation_space, self.action_space)


def register_envs():
    """Registers ``farm/TASK`` with gymnasium for every task (nothing where gymnasium does not
    import, and nothing twice). Returns the ids registered."""
    if gymnasium is None:
        return []
    ids = []
    for task in _farm.task_names():
        env_id = "farm/" + task
        if env_id in gymnasium.registry:
            continue
        kwargs = dict(id=env_id, entry_point="farm.env:Env", kwargs={"config": task})
        try:
            gymnasium.register(vector_entry_point="farm.vector:make_vec", **kwargs)
        except TypeError:  # a gymnasium without vector entry points (before 1.0)
            gymnasium.register(**kwargs)
        ids.append(env_id)
    return ids
