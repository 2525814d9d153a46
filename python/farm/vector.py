"""Vector environments of the farm's tasks: a Gymnasium ``VectorEnv``.

``VecEnv`` subclasses ``gymnasium.vector.VectorEnv`` where gymnasium imports, and a small base with
the same attributes and methods where it does not (Debian 12 has no gymnasium package). It follows
Gymnasium 1.x's vector API (1.1 and later: ``AutoresetMode``, ``reset_mask``):

- Autoreset mode: same step (``metadata["autoreset_mode"]`` is ``AutoresetMode.SAME_STEP``; without
  gymnasium, ``farm.vector.AutoresetMode.SAME_STEP``, a ``str`` equal to Gymnasium's value
  ``"SameStep"``). An env whose episode ends in ``step`` is reset within that step: its row of the
  observations returned is the first of its next episode. ``infos["final_obs"]`` (an object array,
  ``None`` where no episode ended) holds the true last observation where ``infos["_final_obs"]`` is
  True, and ``infos["final_info"]`` (mask ``infos["_final_info"]``) the ended episode's
  ``episode_return``, ``episode_length`` and task ``metrics``, batched as Gymnasium batches a
  sub-environment's info (each key with its ``_key`` mask). ``info_format="0.29"`` writes Gymnasium
  0.29's keys instead: ``final_observation`` and ``final_info``, object arrays of the last
  observation and of the last info dict.
- ``autoreset_mode=AutoresetMode.NEXT_STEP`` (or ``"NextStep"``) gives Gymnasium's next-step mode
  instead, the one its observation wrappers (``NormalizeObservation`` and the others derived from
  ``VectorObservationWrapper``) accept: the step that ends an episode returns its last observation in
  the env's row and the ended episode's ``episode_return``, ``episode_length`` and ``metrics`` in
  ``infos`` (each with its ``_key`` mask, as ``farm.Env``'s info batched); the env's next step ignores
  its action and returns the first observation of the next episode with reward 0, both flags False.
  Gymnasium 0.29's info keys (``info_format="0.29"``) go with the same-step mode only.
- Arrays returned are the caller's own (a copy per step). ``copy=False`` returns the observations as
  a view of the C++ buffer that the next ``step`` or ``reset`` overwrites, as ``SyncVectorEnv`` does
  (in the next-step mode, a step that ends an episode returns a copy: its rows of last observations
  are not in the buffer).
- Rewards are float64, terminations and truncations bool, as ``SyncVectorEnv`` returns them.
- Actions are converted as Gymnasium's envs take them: any real dtype, lists, objects with
  ``__array__`` and PyTorch tensors (on any device); ``(num_envs,)`` for a one-dimensional action.
  What cannot be converted raises a ValueError that names the shape expected.

The GIL is released while the environments step, so other Python threads run meanwhile.
"""
import enum
import os

import numpy as np

from . import _farm
from .spaces import Box, Discrete, batch_space

try:  # pragma: no cover - taken only where gymnasium is installed
    import gymnasium
    from gymnasium.vector import VectorEnv as _Base

    try:
        from gymnasium.vector.vector_env import AutoresetMode
    except ImportError:  # Gymnasium 0.29 has no AutoresetMode
        AutoresetMode = None
    _GymClosedError = getattr(gymnasium.error, "ClosedEnvironmentError", RuntimeError)
except ImportError:
    gymnasium = None
    _Base = None
    AutoresetMode = None
    _GymClosedError = RuntimeError

if AutoresetMode is None:

    class AutoresetMode(str, enum.Enum):
        """Gymnasium 1.x's autoreset modes, with Gymnasium's values (``AutoresetMode.SAME_STEP ==
        "SameStep"``), for where gymnasium.vector has none."""

        NEXT_STEP = "NextStep"
        SAME_STEP = "SameStep"
        DISABLED = "Disabled"


class ClosedEnvironmentError(_GymClosedError):
    """``step`` or ``reset`` of an environment after its ``close()`` (Gymnasium's
    ``ClosedEnvironmentError`` where gymnasium imports)."""


if _Base is None:

    class _Base:
        """The attributes and methods of ``gymnasium.vector.VectorEnv`` (Gymnasium 1.x), for where
        gymnasium does not import."""

        metadata = {}
        spec = None
        render_mode = None
        closed = False
        observation_space = None
        action_space = None
        single_observation_space = None
        single_action_space = None
        num_envs = 0

        def reset(self, *, seed=None, options=None):
            if seed is not None:
                self._np_random, self._np_random_seed = np.random.default_rng(seed), seed

        def step(self, actions):
            raise NotImplementedError

        def render(self):
            raise NotImplementedError("%s render function is not implemented." % self)

        def close(self, **kwargs):
            if self.closed:
                return
            self.close_extras(**kwargs)
            self.closed = True

        def close_extras(self, **kwargs):
            pass

        @property
        def unwrapped(self):
            return self

        def _add_info(self, vector_infos, env_info, env_num):
            """Adds one sub-environment's info to the batched infos, as Gymnasium batches them."""
            for key, value in env_info.items():
                if key == "final_obs":
                    array = vector_infos.get(key)
                    if array is None:
                        array = np.full(self.num_envs, None, dtype=object)
                    array[env_num] = value
                elif isinstance(value, dict):
                    array = self._add_info(vector_infos.get(key, {}), value, env_num)
                else:
                    array = vector_infos.get(key)
                    if array is None:
                        if type(value) in (int, float, bool) or isinstance(value, np.number):
                            array = np.zeros(self.num_envs, dtype=type(value))
                        elif isinstance(value, np.ndarray):
                            array = np.zeros((self.num_envs,) + value.shape, dtype=value.dtype)
                        else:
                            array = np.full(self.num_envs, None, dtype=object)
                    array[env_num] = value
                mask = vector_infos.get("_" + key, np.zeros(self.num_envs, dtype=bool))
                mask[env_num] = True
                vector_infos[key], vector_infos["_" + key] = array, mask
            return vector_infos

        def __del__(self):
            if not getattr(self, "closed", True):
                self.close()

        def __repr__(self):
            if self.spec is None:
                return "%s(num_envs=%d)" % (type(self).__name__, self.num_envs)
            return "%s(%s, num_envs=%d)" % (type(self).__name__, self.spec.id, self.num_envs)


INFO_FORMATS = ("1.x", "0.29")

# The attributes every sub-environment has, all alike (get_attr, call): the envs are C++ states of
# one task, with no Python object each.
_SUB_ENV_ATTRS = {"observation_space": "single_observation_space", "action_space": "single_action_space",
                  "metadata": "metadata", "render_mode": "render_mode", "spec": "spec", "config": "config",
                  "metric_names": "metric_names"}


def to_actions(actions, space, rows):
    """``actions`` as the C++ env takes them: float32 ``(rows, act_dim)`` for a Box of shape
    ``(act_dim,)``, int64 ``(rows,)`` for a Discrete. Converted as Gymnasium's envs take them: any
    real dtype (integers only for a Discrete), lists, ``__array__``, PyTorch tensors, ``(rows,)``
    for a one-dimensional action. Raises a ValueError that names the shape expected."""
    discrete = isinstance(space, Discrete)
    if discrete:
        want = "(%d,) of integers in [0, %d)" % (rows, space.n)
    else:
        dim = space.shape[0]
        want = "(%d, %d)%s of real numbers" % (rows, dim, " or (%d,)" % rows if dim == 1 else "")
    a = actions
    if hasattr(a, "detach") and hasattr(a, "cpu") and hasattr(a, "numpy"):  # a PyTorch tensor
        a = a.detach().cpu().numpy()
    try:
        a = np.asarray(a)
    except (TypeError, ValueError) as e:  # a ragged list, an object without __array__
        raise ValueError("actions: expected shape %s, got %s (%s)" % (want, type(actions).__name__, e)) from None
    got = "shape %s of %s" % (a.shape, a.dtype)
    if discrete:
        if a.shape != (rows,) or a.dtype.kind not in "iu":
            raise ValueError("actions: expected shape %s, got %s" % (want, got))
        return np.ascontiguousarray(a, dtype=np.int64)
    if a.dtype.kind not in "fiu":
        raise ValueError("actions: expected shape %s, got %s" % (want, got))
    if dim == 1 and a.shape == (rows,):
        a = a.reshape(rows, 1)
    if a.shape != (rows, dim):
        raise ValueError("actions: expected shape %s, got %s" % (want, got))
    return np.ascontiguousarray(a, dtype=np.float32)


class VecEnv(_Base):
    """``num_envs`` environments of one task, stepped by ``threads`` C++ threads; a Gymnasium
    ``VectorEnv`` (see the module's documentation)."""

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}
    _np_random = None
    _np_random_seed = None

    def __init__(self, config, num_envs, threads=1, seed=0, copy=True, info_format="1.x", render_mode=None,
                 autoreset_mode=AutoresetMode.SAME_STEP):
        self._core = None  # so that __del__ and close() work on a half-made env
        if info_format not in INFO_FORMATS:
            raise ValueError("info_format: expected one of %s, got %r" % (INFO_FORMATS, info_format))
        modes = (AutoresetMode.SAME_STEP, AutoresetMode.NEXT_STEP)
        value = getattr(autoreset_mode, "value", autoreset_mode)
        mode = next((m for m in modes if m.value == value), None)
        if mode is None:
            raise ValueError("autoreset_mode: expected AutoresetMode.SAME_STEP or NEXT_STEP (or %r, %r), got %r"
                             % (modes[0].value, modes[1].value, autoreset_mode))
        if mode is AutoresetMode.NEXT_STEP and info_format != "1.x":
            raise ValueError("autoreset_mode: Gymnasium 0.29's info keys (info_format=%r) go with the same-step "
                             "mode only" % info_format)
        if render_mode is not None:
            raise ValueError("render_mode: the farm's envs render no frames in Python (None), got %r; "
                             "farm-play records videos of a trained policy" % (render_mode,))
        self.config = os.fspath(config)
        self._core = _farm.VecEnvCore(self.config, int(num_envs), int(threads), int(seed))
        self._args = (self.config, int(num_envs), int(threads), int(seed))
        self.num_envs = self._core.num_envs
        self.threads = self._core.threads
        self.copy = bool(copy)
        self.info_format = info_format
        self.render_mode = None
        self.metadata = dict(type(self).metadata)
        self.metadata["autoreset_mode"] = mode
        self._pending = np.zeros(self.num_envs, dtype=bool)  # next-step mode: envs whose next step resets
        self.metric_names = list(self._core.metric_names)
        self.single_observation_space = Box(-np.inf, np.inf, (self._core.obs_dim,), np.float32)
        if self._core.num_actions > 0:
            self.single_action_space = Discrete(self._core.num_actions)
        else:
            self.single_action_space = Box(-1.0, 1.0, (self._core.act_dim,), np.float32)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.action_shape = self.action_space.shape
        self.closed = False

    @property
    def np_random_seed(self):
        """The seed of ``np_random``: the last int seed given to ``reset``, -1 after ``np_random`` was
        set, or a random one drawn on first use (Gymnasium's ``VectorEnv.np_random_seed``)."""
        if self._np_random_seed is None:
            self._np_random_seed = int(np.random.SeedSequence().entropy)
            self._np_random = np.random.default_rng(self._np_random_seed)
        return self._np_random_seed

    @property
    def np_random(self):
        """A NumPy Generator of the vector env (Gymnasium's ``VectorEnv.np_random``), seeded by
        ``reset(seed=int)``; the envs' own randomness is in C++, seeded as ``reset`` says."""
        if self._np_random is None:
            self.np_random_seed  # noqa: B018 - makes both
        return self._np_random

    @np_random.setter
    def np_random(self, value):
        self._np_random, self._np_random_seed = value, -1

    def _live_core(self, what):
        if self._core is None:
            raise ClosedEnvironmentError("%s of a closed %s: make a new one" % (what, type(self).__name__))
        return self._core

    def reset(self, *, seed=None, options=None):
        """Starts a new episode in every env, or in those of ``options["reset_mask"]`` (a bool array
        of shape ``(num_envs,)``). ``seed``: None continues each env's seed generator; an int
        restarts them as the farm's workers seed theirs (env ``i`` on stream ``i`` of the seed: the
        same seed gives the same observations); a list gives each env its own seed (or None), so an
        env reset with seed ``s`` repeats ``farm.Env`` reset with ``s``. Returns ``(obs, infos)``."""
        core = self._live_core("reset")
        options = dict(options or {})
        mask = options.pop("reset_mask", None)
        if options:
            raise ValueError("reset: the farm's envs take no options but reset_mask, got %s" % sorted(options))
        n = self.num_envs
        seeds = self._seeds(seed)
        if mask is not None:
            mask = np.asarray(mask)
            if mask.shape != (n,) or mask.dtype != np.bool_:
                raise ValueError("reset_mask: expected a bool array of shape (%d,), got shape %s of %s"
                                 % (n, mask.shape, mask.dtype))
            if not mask.any():
                raise ValueError("reset_mask: no env to reset (all False)")
            envs = [i for i in range(n) if mask[i]]
            core.reset_envs(envs, [seeds[i][0] for i in envs], [seeds[i][1] for i in envs])
            self._pending[mask] = False
        elif isinstance(seed, (int, np.integer)) or seed is None:
            core.reset(None if seed is None else int(seed))
            self._pending[:] = False
        else:
            core.reset_envs(list(range(n)), [s for s, _ in seeds], [k for _, k in seeds])
            self._pending[:] = False
        if isinstance(seed, (int, np.integer)):  # np_random, as Gymnasium's base seeds it
            self._np_random, self._np_random_seed = np.random.default_rng(int(seed)), int(seed)
        obs = core.obs()
        return (obs.copy() if self.copy else obs), {}

    def _seeds(self, seed):
        """Per env: (seed or None, stream), the stream as reseed_env takes it."""
        n = self.num_envs
        if seed is None:
            return [(None, 0)] * n
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            if seed < 0:
                raise ValueError("seed: expected a non-negative int, got %d" % seed)
            return [(int(seed), i) for i in range(n)]
        if isinstance(seed, (list, tuple, np.ndarray)):
            if len(seed) != n:
                raise ValueError("seed: expected %d seeds (one per env), got %d" % (n, len(seed)))
            out = []
            for s in seed:
                if s is None:
                    out.append((None, 0))
                elif isinstance(s, (int, np.integer)) and not isinstance(s, bool) and s >= 0:
                    out.append((int(s), 0))
                else:
                    raise ValueError("seed: expected non-negative ints or None, got %r" % (s,))
            return out
        raise ValueError("seed: expected None, an int or a list of %d ints, got %r" % (n, seed))

    def step(self, actions):
        """Steps every env. ``actions``: of shape ``(num_envs, act_dim)`` in [-1, 1] (the task scales
        them), or integers of shape ``(num_envs,)`` for a task of discrete actions; converted as the
        module's documentation says. Returns ``(obs, rewards, terminations, truncations, infos)``."""
        core = self._live_core("step")
        batch = to_actions(actions, self.single_action_space, self.num_envs)
        if self.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP:
            return self._step_next(core, batch)
        core.step(batch)
        obs = core.obs()
        return ((obs.copy() if self.copy else obs), core.rewards().astype(np.float64), core.terminated().copy(),
                core.truncated().copy(), self._infos(core))

    def _step_next(self, core, batch):
        """A step in the next-step mode: envs whose episode ended in the last step are not stepped (the
        C++ env already reset them: their row holds the first observation of the next episode)."""
        core.step(batch, self._pending if self._pending.any() else None)
        obs = core.obs()
        terminated, truncated = core.terminated().copy(), core.truncated().copy()
        self._pending = terminated | truncated
        ended = core.ended()
        infos = {}
        if ended is not None:
            obs = obs.copy()
            obs[ended["env"]] = ended["final_obs"]
            infos = self._infos(core, ended)["final_info"]
        elif self.copy:
            obs = obs.copy()
        return obs, core.rewards().astype(np.float64), terminated, truncated, infos

    def _infos(self, core, ended=None):
        ended = core.ended() if ended is None else ended
        if ended is None:
            return {}
        n, env = self.num_envs, ended["env"]
        mask = np.zeros(n, dtype=bool)
        mask[env] = True
        if self.info_format == "0.29":
            final_obs = np.full(n, None, dtype=object)
            final_info = np.full(n, None, dtype=object)
            for k, i in enumerate(env):
                final_obs[i] = ended["final_obs"][k]
                final_info[i] = _episode_info(ended, k, self.metric_names)
            return {"final_observation": final_obs, "_final_observation": mask, "final_info": final_info,
                    "_final_info": mask.copy()}
        final_obs = np.full(n, None, dtype=object)
        for k, i in enumerate(env):
            final_obs[i] = ended["final_obs"][k]
        r = np.zeros(n, dtype=np.float64)
        r[env] = ended["episode_return"]
        length = np.zeros(n, dtype=np.int64)
        length[env] = ended["episode_length"]
        final_info = {"episode_return": r, "_episode_return": mask.copy(), "episode_length": length,
                      "_episode_length": mask.copy()}
        if self.metric_names:
            values = np.zeros((n, len(self.metric_names)), dtype=np.float64)
            values[env] = ended["metrics"]
            metrics = {}
            for k, name in enumerate(self.metric_names):
                metrics[name], metrics["_" + name] = values[:, k].copy(), mask.copy()
            final_info["metrics"], final_info["_metrics"] = metrics, mask.copy()
        return {"final_obs": final_obs, "_final_obs": mask, "final_info": final_info, "_final_info": mask.copy()}

    def render(self):
        """None: the envs render no frames in Python (``render_mode`` is None, as Gymnasium's envs
        made without one return None)."""
        return None

    def call(self, name, *args, **kwargs):
        """A tuple of ``num_envs`` values of the sub-environments' attribute ``name`` (as
        ``SyncVectorEnv.call``). The sub-environments are C++ states of one task: they share
        ``observation_space``, ``action_space``, ``metadata``, ``render_mode``, ``spec``, ``config``
        and ``metric_names``, and ``render`` gives None each; other names raise AttributeError."""
        if name == "render":
            return tuple(None for _ in range(self.num_envs))
        return self.get_attr(name)

    def get_attr(self, name):
        """A tuple of ``num_envs`` values of the sub-environments' attribute ``name`` (see ``call``)."""
        if name not in _SUB_ENV_ATTRS:
            raise AttributeError("the sub-environments of %s are C++ states of one task with no Python attribute %r; "
                                 "they have %s" % (type(self).__name__, name, ", ".join(sorted(_SUB_ENV_ATTRS))))
        value = getattr(self, _SUB_ENV_ATTRS[name])
        return tuple(value for _ in range(self.num_envs))

    def set_attr(self, name, values):
        """Refused: the sub-environments' attributes are fixed when the env is made (its config).
        Raises AttributeError naming them; make a new env from another config instead."""
        if isinstance(values, (list, tuple)) and len(values) != self.num_envs:
            raise ValueError("Values must be a list or tuple with length equal to the number of environments. "
                             "Got `%d` values for %d environments." % (len(values), self.num_envs))
        raise AttributeError("%s cannot set %r: its sub-environments are C++ states made from the config (%s); "
                             "make a new env from a config with the value changed" %
                             (type(self).__name__, name, self.config))

    def close_extras(self, **kwargs):
        self._core = None  # the C++ envs and threads end here

    def close(self, **kwargs):
        """Ends the C++ envs and their threads. Closing again does nothing; ``step`` or ``reset``
        after it raises ClosedEnvironmentError."""
        if self.closed:
            return
        self.close_extras(**kwargs)
        self.closed = True

    def __getstate__(self):
        raise TypeError("%s cannot be pickled: its environments' state lives in C++. To have one in another "
                        "process, make it there: farm.make_vec(%r, %d, threads=%d, seed=%d)" %
                        ((type(self).__name__,) + self._args))

    def __repr__(self):
        return "%s(%s, num_envs=%d, threads=%d, obs %s, actions %s)" % (
            type(self).__name__, self.config, self.num_envs, self.threads, self.single_observation_space,
            self.single_action_space)


def _episode_info(ended, k, metric_names):
    """Row ``k`` of ``ended`` as one sub-environment's info at its episode's end."""
    info = {"episode_return": float(ended["episode_return"][k]), "episode_length": int(ended["episode_length"][k])}
    if metric_names:
        info["metrics"] = {name: float(ended["metrics"][k][j]) for j, name in enumerate(metric_names)}
    return info


def make_vec(config, num_envs, threads=1, seed=0, copy=True, info_format="1.x", render_mode=None,
             autoreset_mode=AutoresetMode.SAME_STEP):
    """A VecEnv of the task a config names: a config file's path (its ``task`` section; a task of
    terms reads its model from the config's folder), or a task name (``farm.task_names()``) with
    that task's defaults. ``copy=False``: observations as views (see the module's documentation);
    ``info_format="0.29"``: Gymnasium 0.29's info keys; ``autoreset_mode=AutoresetMode.NEXT_STEP``:
    Gymnasium's next-step autoreset, which its observation wrappers require."""
    return VecEnv(config, num_envs, threads, seed, copy=copy, info_format=info_format, render_mode=render_mode,
                  autoreset_mode=autoreset_mode)
