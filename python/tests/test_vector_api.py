"""farm.make_vec against Gymnasium 1.x's VectorEnv API, over every task the farm runs: attributes,
batched spaces, dtypes, same-step autoreset and its info keys, next-step autoreset against
Gymnasium's algorithm over single envs, seeding (int, list, partial resets),
action conversions, copies against views, close, pickling; farm.Env, the single env; and a
CleanRL-style loop that stores distinct obs and next_obs. Runs with gymnasium absent (Debian has no
package) and, where it imports, against its classes."""
import os
import pickle

import numpy as np
import pytest
import torch

import farm
from farm import vector

SOURCE = os.environ.get("FARM_SOURCE_DIR", os.path.join(os.path.dirname(__file__), "..", ".."))
N = 3

try:
    import gymnasium
except ImportError:
    gymnasium = None


def task_configs():
    """Every task of farm.task_names(): by name with its defaults, the task of terms by the A1's
    config (it needs a model), the mclari with 3-step episodes (its default steps take up to 1 s)."""
    out = []
    for task in farm.task_names():
        if task == "terms":
            out.append(pytest.param(os.path.join(SOURCE, "deploy", "configs", "a1_terms_ppo.txtpb"), id="terms"))
        elif task == "mclari":
            out.append(pytest.param("mclari:short", id="mclari"))
        else:
            out.append(pytest.param(task, id=task))
    return out


@pytest.fixture
def config(request, tmp_path):
    c = request.param
    if c == "mclari:short":
        path = tmp_path / "mclari.txtpb"
        path.write_text('experiment_id: "python_mclari"\ntask { name: "mclari" mclari { max_episode_steps: 3 } }\n')
        return str(path)
    return c


def small_actions(env, rng):
    """Valid actions: random indices, or small random values (large ones slow the mclari's steps)."""
    if isinstance(env.single_action_space, farm.Discrete):
        return rng.integers(env.single_action_space.n, size=env.num_envs)
    return rng.uniform(-0.2, 0.2, env.action_space.shape).astype(np.float32)


def test_every_task_is_listed():
    ids = [p.id for p in task_configs()]
    assert ids == list(farm.task_names()) and "pendulum" in ids and len(ids) >= 8


@pytest.mark.parametrize("config", task_configs(), indirect=True)
def test_attributes_spaces_and_dtypes(config):
    env = farm.make_vec(config, N, seed=1)
    base = gymnasium.vector.VectorEnv if gymnasium else vector._Base
    assert isinstance(env, base)
    assert env.num_envs == N and env.closed is False and env.render_mode is None and env.spec is None
    assert env.unwrapped is env
    mode = env.metadata["autoreset_mode"]
    assert mode == farm.AutoresetMode.SAME_STEP and mode.value == "SameStep"
    if gymnasium is not None and hasattr(gymnasium.vector.vector_env, "AutoresetMode"):
        assert mode is gymnasium.vector.vector_env.AutoresetMode.SAME_STEP
    single_obs, single_act = env.single_observation_space, env.single_action_space
    assert single_obs.dtype == np.float32 and len(single_obs.shape) == 1
    assert env.observation_space.shape == (N,) + single_obs.shape and env.observation_space.dtype == np.float32
    if isinstance(single_act, farm.Discrete):
        assert single_act.n > 1
        assert isinstance(env.action_space, farm.MultiDiscrete) and env.action_space.shape == (N,)
        assert np.all(env.action_space.nvec == single_act.n)
    else:
        assert single_act.dtype == np.float32 and np.all(single_act.low == -1) and np.all(single_act.high == 1)
        assert env.action_space.shape == (N,) + single_act.shape
    for name in ("call", "get_attr", "set_attr", "render", "close", "close_extras"):
        assert callable(getattr(env, name))
    assert isinstance(env.np_random, np.random.Generator)

    obs, infos = env.reset(seed=4)
    assert infos == {}
    assert obs.shape == (N,) + single_obs.shape and obs.dtype == np.float32 and np.isfinite(obs).all()
    assert env.observation_space.contains(obs)
    assert env.np_random_seed == 4
    env.action_space.seed(4)
    sample = env.action_space.sample()
    assert env.action_space.contains(sample)
    obs, rewards, terms, truncs, infos = env.step(sample)
    assert obs.shape == (N,) + single_obs.shape and obs.dtype == np.float32
    assert rewards.shape == (N,) and rewards.dtype == np.float64
    assert terms.shape == truncs.shape == (N,) and terms.dtype == truncs.dtype == np.bool_
    assert isinstance(infos, dict)

    assert env.get_attr("observation_space") == (single_obs,) * N
    assert env.call("action_space") == (single_act,) * N
    assert env.call("render") == (None,) * N and env.render() is None
    with pytest.raises(AttributeError, match="no Python attribute 'gravity'"):
        env.get_attr("gravity")
    with pytest.raises(AttributeError, match="cannot set 'gravity'"):
        env.set_attr("gravity", 1.0)


@pytest.mark.parametrize("config", task_configs(), indirect=True)
def test_same_step_autoreset_and_its_info_keys(config):
    env = farm.make_vec(config, N, seed=2)
    obs, _ = env.reset(seed=2)
    rng = np.random.default_rng(2)
    for _ in range(3000):
        prev = obs
        obs, rewards, terms, truncs, infos = env.step(small_actions(env, rng))
        done = terms | truncs
        assert not (terms & truncs).any()
        if not done.any():
            assert infos == {}
            continue
        assert sorted(infos) == ["_final_info", "_final_obs", "final_info", "final_obs"]
        assert np.array_equal(infos["_final_obs"], done) and np.array_equal(infos["_final_info"], done)
        final_obs, final_info = infos["final_obs"], infos["final_info"]
        assert final_obs.dtype == object and final_obs.shape == (N,)
        for i in range(N):
            if done[i]:
                assert final_obs[i].shape == obs[i].shape and final_obs[i].dtype == np.float32
                # The returned row starts the next episode; the last one of the ended episode is
                # in final_obs, and it is not the row before it.
                assert not np.array_equal(final_obs[i], obs[i])
            else:
                assert final_obs[i] is None
        assert final_info["episode_return"].dtype == np.float64
        assert final_info["episode_length"].dtype == np.int64
        assert np.array_equal(final_info["_episode_return"], done)
        assert np.all(final_info["episode_length"][done] > 0) and np.all(final_info["episode_length"][~done] == 0)
        for name in env.metric_names:
            assert np.array_equal(final_info["metrics"]["_" + name], done)
        # No top-level "episode": Gymnasium's RecordEpisodeStatistics writes that key itself.
        assert "episode" not in infos and "episode" not in final_info
        # The next step continues the new episodes.
        _, _, terms, truncs, infos = env.step(small_actions(env, rng))
        assert not (done & (terms | truncs)).any()
        break
    else:
        pytest.fail("no episode ended in 3000 steps")
    assert prev.shape == obs.shape


@pytest.mark.parametrize("config", task_configs(), indirect=True)
def test_next_step_autoreset_is_gymnasiums_over_single_envs(config):
    # Gymnasium's next-step autoreset (SyncVectorEnv's step with AutoresetMode.NEXT_STEP) written out
    # over N farm.Env, each reset with its own seed, against farm.make_vec in that mode reset with the
    # list of those seeds: the same observations, rewards, flags and episode infos at every step.
    seeds = [11 + i for i in range(N)]
    env = farm.make_vec(config, N, autoreset_mode=farm.AutoresetMode.NEXT_STEP)
    assert env.metadata["autoreset_mode"] == farm.AutoresetMode.NEXT_STEP
    singles = [farm.Env(config) for _ in range(N)]
    obs, _ = env.reset(seed=seeds)
    assert np.array_equal(obs, np.stack([e.reset(seed=s)[0] for e, s in zip(singles, seeds)]))
    autoreset = np.zeros(N, dtype=bool)
    rng = np.random.default_rng(4)
    ended = resets = 0
    for _ in range(3000):
        act = small_actions(env, rng)
        obs, rewards, terms, truncs, infos = env.step(act)
        assert rewards.dtype == np.float64 and terms.dtype == np.bool_
        for i, single in enumerate(singles):
            if autoreset[i]:  # Gymnasium resets the sub-env and ignores its action
                o, _ = single.reset()
                r, t, u, info = 0.0, False, False, {}
                resets += 1
            else:
                o, r, t, u, info = single.step(act[i])
            assert np.array_equal(obs[i], o) and (rewards[i], terms[i], truncs[i]) == (r, t, u)
            if info:
                assert infos["_episode_length"][i] and infos["episode_length"][i] == info["episode_length"]
                assert infos["episode_return"][i] == info["episode_return"]
                for name in env.metric_names:
                    assert infos["metrics"][name][i] == info["metrics"][name]
            else:
                assert not infos or not infos["_episode_length"][i]
        autoreset = terms | truncs
        ended += int(autoreset.sum())
        if resets >= 2:
            break
    assert ended >= 2 and resets >= 2, "%d episodes ended, %d next-step resets in 3000 steps" % (ended, resets)
    with pytest.raises(ValueError, match="autoreset_mode: expected"):
        farm.make_vec(config, N, autoreset_mode="Disabled")
    with pytest.raises(ValueError, match="same-step mode only"):
        farm.make_vec(config, N, info_format="0.29", autoreset_mode="NextStep")


@pytest.mark.parametrize("config", task_configs(), indirect=True)
def test_seeding(config):
    a, b = farm.make_vec(config, N, seed=0), farm.make_vec(config, N, seed=5)
    oa, _ = a.reset(seed=7)
    ob, _ = b.reset(seed=7)
    assert np.array_equal(oa, ob)  # an int seed restarts every env's generator, whatever came before
    acts = [small_actions(a, np.random.default_rng(k)) for k in range(5)]
    for act in acts:
        oa, ra, *_ = a.step(act)
        ob, rb, *_ = b.step(act)
        assert np.array_equal(oa, ob) and np.array_equal(ra, rb)
    # A list: env i on its own seed, as the single env reset with it; None keeps env i's generator.
    single = farm.Env(config)
    obs, _ = a.reset(seed=[11, None, 12])
    assert np.array_equal(obs[0], single.reset(seed=11)[0])
    assert np.array_equal(obs[2], single.reset(seed=12)[0])
    again, _ = a.reset(seed=[11, None, 12])
    assert np.array_equal(again[0], obs[0]) and np.array_equal(again[2], obs[2])
    # A mask resets its envs alone; with an int seed, as the full reset with that seed resets them.
    full, _ = b.reset(seed=9)
    for act in acts[:2]:
        moved, *_ = a.step(act)
    moved = moved.copy()
    mask = np.array([False, True, False])
    part, infos = a.reset(seed=9, options={"reset_mask": mask})
    assert infos == {}
    assert np.array_equal(part[1], full[1])
    assert np.array_equal(part[0], moved[0]) and np.array_equal(part[2], moved[2])
    part, _ = a.reset(seed=[None, 11, None], options={"reset_mask": mask})
    assert np.array_equal(part[1], single.reset(seed=11)[0])
    with pytest.raises(ValueError, match=r"reset_mask: expected a bool array of shape \(3,\)"):
        a.reset(options={"reset_mask": [1, 0, 0]})
    with pytest.raises(ValueError, match="all False"):
        a.reset(options={"reset_mask": np.zeros(N, bool)})
    with pytest.raises(ValueError, match="no options but reset_mask"):
        a.reset(options={"difficulty": 2})
    with pytest.raises(ValueError, match="expected 3 seeds"):
        a.reset(seed=[1, 2])
    with pytest.raises(ValueError, match="non-negative"):
        a.reset(seed=-1)


class ArrayLike:
    """An object NumPy converts through __array__, as Gymnasium's envs take it."""

    def __init__(self, a):
        self.a = a

    def __array__(self, dtype=None):
        return np.asarray(self.a, dtype=dtype)


@pytest.mark.parametrize("config", task_configs(), indirect=True)
def test_action_conversions(config):
    ref = farm.make_vec(config, N, seed=3)
    env = farm.make_vec(config, N, seed=3)
    ref.reset(seed=3)
    env.reset(seed=3)
    rng = np.random.default_rng(3)
    discrete = isinstance(env.single_action_space, farm.Discrete)
    base = small_actions(env, rng)
    forms = [base.tolist(), ArrayLike(base), torch.from_numpy(np.array(base))]
    if discrete:
        forms += [base.astype(np.int32), base.astype(np.uint8)]
    else:
        forms += [base.astype(np.float64)]
        if env.single_action_space.shape == (1,):
            forms += [base[:, 0].astype(np.float64)]  # (num_envs,) for a one-dimensional action
    for form in forms:
        want, *_ = ref.step(base)
        got, *_ = env.step(form)
        assert np.array_equal(got, want), type(form)
    shape = r"\(3,\) of integers in \[0, %d\)" % env.single_action_space.n if discrete else r"\(3, %d\)" % (
        env.single_action_space.shape[0])
    bad = [np.zeros((N + 1,) + base.shape[1:], base.dtype), np.array(["a"] * N), np.zeros(base.shape, bool),
           [[0.0, 1.0], [0.0]]]
    if discrete:
        bad += [base.astype(np.float32), base.reshape(N, 1)]
    for b in bad:
        with pytest.raises(ValueError, match="actions: expected shape " + shape):
            env.step(b)


@pytest.mark.parametrize("config", task_configs(), indirect=True)
def test_copies_by_default_views_on_request(config):
    rng = np.random.default_rng(4)
    own = farm.make_vec(config, N, seed=4)
    first, _ = own.reset(seed=4)
    kept = first.copy()
    second, r1, t1, u1, _ = own.step(small_actions(own, rng))
    third, r2, t2, u2, _ = own.step(small_actions(own, rng))
    assert np.array_equal(first, kept)  # not overwritten by the steps
    for x, y in ((first, second), (second, third), (r1, r2), (t1, t2), (u1, u2)):
        assert not np.shares_memory(x, y)
    views = farm.make_vec(config, N, seed=4, copy=False)
    first, _ = views.reset(seed=4)
    second, r1, *_ = views.step(small_actions(views, rng))
    third, r2, *_ = views.step(small_actions(views, rng))
    assert np.shares_memory(first, second) and np.shares_memory(second, third)
    assert not np.shares_memory(r1, r2)  # rewards and flags are fresh either way, as SyncVectorEnv's


@pytest.mark.parametrize("config", task_configs(), indirect=True)
def test_close_and_pickle(config):
    env = farm.make_vec(config, N, seed=5)
    env.reset(seed=5)
    with pytest.raises(TypeError, match=r"cannot be pickled.*farm.make_vec\("):
        pickle.dumps(env)
    env.close()
    assert env.closed
    env.close()  # again: nothing
    with pytest.raises(farm.ClosedEnvironmentError, match="step of a closed VecEnv"):
        env.step(small_actions(farm.make_vec(config, N), np.random.default_rng(5)))
    with pytest.raises(farm.ClosedEnvironmentError, match="reset of a closed VecEnv"):
        env.reset()


@pytest.mark.parametrize("config", task_configs(), indirect=True)
def test_single_env(config):
    env = farm.Env(config, seed=6)
    base = gymnasium.Env if gymnasium else farm.env._Base
    assert isinstance(env, base)
    vec = farm.make_vec(config, 1, seed=6)
    # The single env's episodes are env 0's of a one-env VecEnv of the same seed, autoresets included.
    obs, info = env.reset()
    vobs, _ = vec.reset()
    assert info == {} and np.array_equal(obs, vobs[0]) and env.observation_space.contains(obs)
    rng = np.random.default_rng(6)
    ended = 0
    for _ in range(3000):
        act = small_actions(vec, rng)
        obs, reward, term, trunc, info = env.step(act[0])
        vobs, vr, vt, vu, vinfo = vec.step(act)
        assert isinstance(reward, float) and reward == vr[0] and term == vt[0] and trunc == vu[0]
        if term or trunc:
            ended += 1
            assert np.array_equal(obs, vinfo["final_obs"][0])
            assert info["episode_length"] == vinfo["final_info"]["episode_length"][0]
            obs, _ = env.reset()
        assert np.array_equal(obs, vobs[0])
        if ended == 2:
            break
    assert ended >= 1
    for bad in (np.zeros((2, 2, 2)), "a", [0.5, "a"]):
        with pytest.raises(ValueError, match=r"^action: expected"):
            env.step(bad)
    if isinstance(env.action_space, farm.Discrete):
        with pytest.raises(ValueError, match=r"^action: expected an integer in \[0, %d\)" % env.action_space.n):
            env.step(0.5)
    env.close()
    env.close()
    with pytest.raises(farm.ClosedEnvironmentError):
        env.step(act[0])


def test_cleanrl_style_loop_stores_distinct_obs_and_next_obs():
    # CleanRL's off-policy data path (sac_continuous_action.py), with the 1.x keys: the truncated
    # envs' next observation from final_obs, the buffer given obs and next_obs, then obs = next_obs.
    def collect(copy):
        envs = farm.make_vec("pendulum", 4, seed=8, copy=copy)
        obs, _ = envs.reset(seed=8)
        envs.action_space.seed(8)
        stored = []
        for _ in range(450):
            actions = envs.action_space.sample()
            next_obs, rewards, terminations, truncations, infos = envs.step(actions)
            real_next_obs = next_obs.copy()
            for idx, trunc in enumerate(truncations):
                if trunc:
                    real_next_obs[idx] = infos["final_obs"][idx]
            stored.append((np.array(obs), real_next_obs))  # the buffer copies what it is given
            obs = next_obs
        o = np.concatenate([s[0] for s in stored])
        n = np.concatenate([s[1] for s in stored])
        return int(np.all(o == n, axis=1).sum()), len(o)

    same, rows = collect(copy=True)
    assert rows == 1800 and same == 0
    # The views that copy=False returns are what corrupted such a loop: obs is next_obs's buffer,
    # already overwritten when the buffer copies it, so every row but those of the 2 x 4 truncations
    # (next_obs from final_obs) holds one observation twice.
    same, rows = collect(copy=False)
    assert same == rows - 8


def test_gymnasium_0_29_info_keys():
    env = farm.make_vec("pendulum", 2, seed=9, info_format="0.29")
    env.reset(seed=9)
    for _ in range(200):
        obs, _, _, truncs, infos = env.step(np.zeros((2, 1)))
    assert truncs.all()
    assert sorted(infos) == ["_final_info", "_final_observation", "final_info", "final_observation"]
    for i in range(2):
        assert infos["final_observation"][i].shape == (3,)
        assert infos["final_info"][i]["episode_length"] == 200
    with pytest.raises(ValueError, match="info_format"):
        farm.make_vec("pendulum", 2, info_format="0.28")
