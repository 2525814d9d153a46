"""farm's envs under Gymnasium itself: its vector wrappers wrap farm.make_vec, gymnasium.make and
make_vec take the registered ids farm/TASK, its env checker passes farm.Env, and its SyncVectorEnv
over farm.Env steps as farm.make_vec does. Skipped where gymnasium does not import (Debian 12 has no
package); put Gymnasium 1.1 or later on PYTHONPATH to run them."""
import numpy as np
import pytest

import farm

gymnasium = pytest.importorskip("gymnasium")
try:
    from gymnasium.vector.vector_env import AutoresetMode
except ImportError:
    pytest.skip("Gymnasium %s: farm follows 1.1 and later (AutoresetMode)" % gymnasium.__version__,
                allow_module_level=True)
from gymnasium.wrappers import vector as vw  # noqa: E402


def test_it_is_a_vector_env_with_gymnasium_spaces():
    env = farm.make_vec("pendulum", 3)
    assert isinstance(env, gymnasium.vector.VectorEnv)
    assert env.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP
    assert isinstance(env.single_observation_space, gymnasium.spaces.Box)
    assert env.action_space == gymnasium.vector.utils.batch_space(env.single_action_space, 3)
    jet = farm.make_vec("jetbot", 3)
    assert isinstance(jet.single_action_space, gymnasium.spaces.Discrete)
    assert isinstance(jet.action_space, gymnasium.spaces.MultiDiscrete)


def test_vector_wrappers_wrap_it():
    # Gymnasium's observation wrappers (NormalizeObservation: a VectorObservationWrapper) take a
    # next-step or disabled env only: farm.make_vec's next-step mode.
    raw = farm.make_vec("pendulum", 4, seed=1)
    wrapped = farm.make_vec("pendulum", 4, seed=1, autoreset_mode=AutoresetMode.NEXT_STEP)
    env = vw.RecordEpisodeStatistics(vw.NormalizeObservation(vw.ClipAction(wrapped)))
    raw_obs, _ = raw.reset(seed=1)
    obs, _ = env.reset(seed=1)
    assert obs.shape == raw_obs.shape and not np.allclose(obs, raw_obs)  # normalized
    for step in range(200):
        obs, rewards, terms, truncs, infos = env.step(np.full((4, 1), 5.0))  # ClipAction: 1.0
        _, raw_rewards, _, _, raw_infos = raw.step(np.ones((4, 1), np.float32))
        assert np.allclose(rewards, raw_rewards)
    assert truncs.all() and infos["_episode"].all()
    assert np.all(infos["episode"]["l"] == 200)
    assert np.allclose(infos["episode"]["r"], raw_infos["final_info"]["episode_return"], atol=1e-2)


def test_registered_ids():
    env = gymnasium.make("farm/pendulum")
    obs, _ = env.reset(seed=3)
    assert np.array_equal(obs, farm.Env("pendulum").reset(seed=3)[0])
    env.step(env.action_space.sample())
    venv = gymnasium.make_vec("farm/jetbot", num_envs=3)
    assert isinstance(venv.unwrapped, farm.VecEnv) and venv.num_envs == 3
    venv.reset(seed=0)
    venv.step(venv.action_space.sample())


def test_env_checker_passes_the_single_env():
    from gymnasium.utils.env_checker import check_env

    check_env(farm.Env("pendulum"))
    check_env(farm.Env("jetbot"))


def test_sync_vector_env_of_single_envs_steps_as_make_vec():
    # Gymnasium's own same-step vector env over farm.Env, env i reset with seed 7 + i, and
    # farm.make_vec reset with the list of those seeds: the same episodes, autoresets included.
    sync = gymnasium.vector.SyncVectorEnv([lambda: farm.Env("pendulum") for _ in range(2)],
                                          autoreset_mode=AutoresetMode.SAME_STEP)
    ours = farm.make_vec("pendulum", 2)
    a, _ = sync.reset(seed=7)
    b, _ = ours.reset(seed=[7, 8])
    assert np.array_equal(a, b)
    rng = np.random.default_rng(7)
    for _ in range(250):
        act = rng.uniform(-1, 1, (2, 1)).astype(np.float32)
        a, ra, ta, ua, ia = sync.step(act)
        b, rb, tb, ub, ib = ours.step(act)
        assert np.array_equal(a, b) and np.array_equal(ra, rb) and np.array_equal(ua, ub)
        assert ra.dtype == rb.dtype
        if ua.any():
            for i in range(2):
                assert np.array_equal(ia["final_obs"][i], ib["final_obs"][i])


def test_sync_vector_env_next_step_steps_as_make_vec_next_step():
    sync = gymnasium.vector.SyncVectorEnv([lambda: farm.Env("pendulum") for _ in range(2)],
                                          autoreset_mode=AutoresetMode.NEXT_STEP)
    ours = farm.make_vec("pendulum", 2, autoreset_mode=AutoresetMode.NEXT_STEP)
    a, _ = sync.reset(seed=7)
    b, _ = ours.reset(seed=[7, 8])
    assert np.array_equal(a, b)
    rng = np.random.default_rng(7)
    resets = 0
    for _ in range(450):
        act = rng.uniform(-1, 1, (2, 1)).astype(np.float32)
        a, ra, ta, ua, ia = sync.step(act)
        b, rb, tb, ub, ib = ours.step(act)
        assert np.array_equal(a, b) and np.array_equal(ra, rb) and np.array_equal(ua, ub) and np.array_equal(ta, tb)
        if ua.any():
            assert np.array_equal(ia["episode_return"], ib["episode_return"])
        resets += int(np.all(ra == 0))
    assert resets >= 2  # two next-step resets compared
