"""The farm from Python.

- ``make_vec(config, num_envs, threads=1, seed=0, copy=True)``: a batch of environments of any task
  the farm runs, on the farm's C++ vector env: a Gymnasium ``VectorEnv`` (``farm.vector``).
- ``Env(config, seed=0)``: one environment, a Gymnasium ``Env`` (``farm.env``); where gymnasium
  imports, ``gymnasium.make("farm/TASK")`` and ``gymnasium.make_vec("farm/TASK", num_envs)``.
- ``farm.sb3.SB3VecEnv(make_vec(...))``: Stable-Baselines3's ``VecEnv`` interface over a VecEnv.
- ``load_policy(path)``: a trained policy (``RUN/best``, ``RUN/checkpoint`` or a ``policy.bin``) as a
  callable that computes the action a worker's evaluation computes (``farm.runs``).
- ``read_run(folder)``: a run folder's CSV (pandas), events, summary and manifests (``farm.runs``).
- ``LearnerBus(config, domain)``: the learner's side of the bus for an algorithm in Python: the
  experiment's spec out, the workers' checked and accounted batches in, policies out;
  ``farm.torch_policy`` turns a PyTorch ``nn.Sequential`` into the workers' layout.
"""
from ._farm import ConfigError, task_names

try:
    from ._farm import LearnerBus
except ImportError:  # a build without DDS
    LearnerBus = None
from .runs import Policy, Run, load_policy, read_run
from .spaces import Box, Discrete, MultiDiscrete
from .vector import AutoresetMode, ClosedEnvironmentError, VecEnv, make_vec
from .env import Env, register_envs

register_envs()

__all__ = ["ConfigError", "task_names", "make_vec", "VecEnv", "Env", "AutoresetMode", "ClosedEnvironmentError",
           "Box", "Discrete", "MultiDiscrete", "load_policy", "Policy", "read_run", "Run", "LearnerBus"]
