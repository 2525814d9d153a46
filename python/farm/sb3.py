"""Stable-Baselines3's ``VecEnv`` interface over a ``farm.VecEnv``.

``SB3VecEnv(farm.make_vec(...))`` subclasses ``stable_baselines3.common.vec_env.VecEnv`` where
stable_baselines3 imports, and a base with the same methods where it does not, so that SB3's
algorithms (``SAC("MlpPolicy", SB3VecEnv(...))``) and code written to that interface take it:

- ``reset()`` returns the observations only; the seeds of ``seed(s)`` (``s + i`` for env ``i``)
  and the options of ``set_options`` apply at the next ``reset()``, as in SB3.
- ``step_wait()`` returns ``(obs, rewards, dones, infos)``: rewards float32, dones bool, and
  ``infos`` a list of one dict per env. An env whose episode ended has, in its dict, the
  ``terminal_observation``, ``TimeLimit.truncated`` (a time limit, not a true end: bootstrap) and
  ``episode`` (``r``, ``l``, ``t``, as SB3's ``Monitor`` writes it).
- Every array returned is the caller's own: SB3 keeps ``new_obs`` as the next step's ``obs``, so an
  env returning views of its buffers would have it store ``obs == next_obs``.
"""
import time

import numpy as np

try:  # pragma: no cover - taken only where stable_baselines3 is installed
    from stable_baselines3.common.vec_env import VecEnv as _Base
except ImportError:
    _Base = None

if _Base is None:

    class _Base:
        """The concrete methods of ``stable_baselines3.common.vec_env.VecEnv`` (SB3 2.x), for where
        stable_baselines3 does not import."""

        def __init__(self, num_envs, observation_space, action_space):
            self.num_envs = num_envs
            self.observation_space = observation_space
            self.action_space = action_space
            self.reset_infos = [{} for _ in range(num_envs)]
            self._seeds = [None for _ in range(num_envs)]
            self._options = [{} for _ in range(num_envs)]
            self.render_mode = self.get_attr("render_mode")[0]
            self.metadata = {"render_modes": []}

        def _reset_seeds(self):
            self._seeds = [None for _ in range(self.num_envs)]

        def _reset_options(self):
            self._options = [{} for _ in range(self.num_envs)]

        def step(self, actions):
            self.step_async(actions)
            return self.step_wait()

        def get_images(self):
            raise NotImplementedError

        def render(self, mode=None):
            return None

        def seed(self, seed=None):
            if seed is None:
                seed = int(np.random.randint(0, np.iinfo(np.uint32).max, dtype=np.uint32))
            self._seeds = [seed + idx for idx in range(self.num_envs)]
            return self._seeds

        def set_options(self, options=None):
            if options is None:
                options = {}
            self._options = list(options) if isinstance(options, list) else [options] * self.num_envs

        @property
        def unwrapped(self):
            return self

        def getattr_depth_check(self, name, already_found):
            if hasattr(self, name) and already_found:
                return "%s.%s" % (type(self).__module__, type(self).__name__)
            return None

        def _get_indices(self, indices):
            if indices is None:
                return range(self.num_envs)
            if isinstance(indices, int):
                return [indices]
            return indices


class SB3VecEnv(_Base):
    """SB3's ``VecEnv`` over ``venv``, a ``farm.VecEnv`` (see the module's documentation)."""

    def __init__(self, venv):
        mode = getattr(venv, "metadata", {}).get("autoreset_mode")
        if getattr(mode, "value", mode) != "SameStep":
            raise ValueError("SB3VecEnv: SB3's VecEnv resets an env in the step that ends its episode; give it a "
                             "farm.make_vec in the same-step mode (the default), got autoreset_mode %r" % (mode,))
        self.venv = venv
        self._actions = None
        self._started = np.full(venv.num_envs, time.monotonic())
        super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)

    def reset(self):
        seeds = self._seeds
        if any(o for o in self._options):
            raise ValueError("reset: the farm's envs take no options, got %s" % self._options)
        if all(s is None for s in seeds):
            obs, _ = self.venv.reset()
        else:
            obs, _ = self.venv.reset(seed=list(seeds))
        self._reset_seeds()
        self._reset_options()
        self.reset_infos = [{} for _ in range(self.num_envs)]
        self._started[:] = time.monotonic()
        return np.array(obs)  # the caller's own, whatever the VecEnv's copy setting

    def step_async(self, actions):
        self._actions = actions

    def step_wait(self):
        actions, self._actions = self._actions, None
        obs, rewards, term, trunc, infos = self.venv.step(actions)
        obs = np.array(obs)
        dones = term | trunc
        out = [{} for _ in range(self.num_envs)]
        if dones.any():
            now = time.monotonic()
            final_obs, final_info = self._final(infos)
            for i in np.flatnonzero(dones):
                info = out[i]
                info["terminal_observation"] = np.array(final_obs[i])
                info["TimeLimit.truncated"] = bool(trunc[i] and not term[i])
                last = final_info[i]
                info["episode"] = {"r": last["episode_return"], "l": last["episode_length"],
                                   "t": round(now - self._started[i], 6)}
                if "metrics" in last:
                    info["metrics"] = last["metrics"]
                self._started[i] = now
        return obs, rewards.astype(np.float32), dones, out

    def _final(self, infos):
        """Per env: the last observation and the ended episode's info, from either info format."""
        if "final_observation" in infos:  # Gymnasium 0.29's
            return infos["final_observation"], infos["final_info"]
        fi = infos["final_info"]
        last = [None] * self.num_envs
        for i in np.flatnonzero(infos["_final_info"]):
            d = {"episode_return": float(fi["episode_return"][i]), "episode_length": int(fi["episode_length"][i])}
            if "metrics" in fi:
                d["metrics"] = {k: float(v[i]) for k, v in fi["metrics"].items() if not k.startswith("_")}
            last[i] = d
        return infos["final_obs"], last

    def close(self):
        self.venv.close()

    def get_attr(self, attr_name, indices=None):
        values = self.venv.get_attr(attr_name)
        return [values[i] for i in self._get_indices(indices)]

    def set_attr(self, attr_name, value, indices=None):
        self.venv.set_attr(attr_name, value)  # refused with an AttributeError that says why

    def env_method(self, method_name, *method_args, indices=None, **method_kwargs):
        values = self.venv.call(method_name, *method_args, **method_kwargs)
        return [values[i] for i in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class, indices=None):
        """False for each env: the farm's envs are wrapped by no Gymnasium or SB3 wrapper (``Monitor``
        included; the ``episode`` entries are the adapter's own)."""
        return [False for _ in self._get_indices(indices)]

    def __getstate__(self):
        return self.venv.__getstate__()  # refused, saying how to make one in another process
