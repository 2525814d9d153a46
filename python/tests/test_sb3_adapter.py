"""farm.sb3.SB3VecEnv: Stable-Baselines3's VecEnv interface over farm.make_vec, and an SB3-style SAC
loop over it that reaches the pendulum target. SB3 is not a Debian package: the loop below is SB3's
off-policy data path written out (OffPolicyAlgorithm.collect_rollouts, _store_transition,
ReplayBuffer.add with handle_timeout_termination), with SAC's update in PyTorch."""
import os
import pickle
import time

import numpy as np
import pytest
import torch
from torch import nn
from torch.nn import functional as F

import farm
from farm.sb3 import SB3VecEnv

SOURCE = os.environ.get("FARM_SOURCE_DIR", os.path.join(os.path.dirname(__file__), "..", ".."))


def pendulum_target():
    """deploy/configs/pendulum_sac.txtpb's stop rule: the quickstart's target return."""
    text = open(os.path.join(SOURCE, "deploy", "configs", "pendulum_sac.txtpb")).read()
    return float(next(line.split(":")[1] for line in text.splitlines() if "target_eval_return" in line))


def test_the_vecenv_interface():
    venv = SB3VecEnv(farm.make_vec("pendulum", 3, seed=0))
    assert venv.num_envs == 3
    assert venv.observation_space.shape == (3,) and venv.action_space.shape == (1,)
    assert venv.seed(5) == [5, 6, 7]
    obs = venv.reset()  # SB3: observations only
    assert isinstance(obs, np.ndarray) and obs.shape == (3, 3)
    # The seeds of seed() apply at that reset only: env i on seed 5 + i, as one env reset with it.
    for i in range(3):
        single, _ = farm.Env("pendulum").reset(seed=5 + i)
        assert np.array_equal(obs[i], single)
    assert venv.get_attr("render_mode") == [None, None, None]
    assert venv.get_attr("action_space", indices=[1]) == [venv.action_space]
    assert venv.env_method("render", indices=0) == [None]
    assert venv.env_is_wrapped(object) == [False, False, False]
    with pytest.raises(AttributeError, match="cannot set 'gravity'"):
        venv.set_attr("gravity", 1.0)
    with pytest.raises(TypeError, match="cannot be pickled.*make_vec"):
        pickle.dumps(venv)
    for step in range(1, 201):
        venv.step_async(np.full((3, 1), 0.3, np.float32))
        new_obs, rewards, dones, infos = venv.step_wait()
        assert rewards.dtype == np.float32 and dones.dtype == np.bool_ and len(infos) == 3
        if step < 200:
            assert not dones.any() and infos == [{}, {}, {}]
    # The pendulum's episodes are cut at 200 steps: a time limit, which SB3 bootstraps through.
    assert dones.all()
    for i, info in enumerate(infos):
        assert info["TimeLimit.truncated"] is True and info["episode"]["l"] == 200
        assert info["terminal_observation"].shape == (3,)
        assert not np.array_equal(info["terminal_observation"], new_obs[i])  # new_obs starts the next
    venv.close()
    venv.close()
    # SB3 reads the reset observation in the step that ends an episode: a next-step env is refused.
    with pytest.raises(ValueError, match="same-step mode"):
        SB3VecEnv(farm.make_vec("pendulum", 3, autoreset_mode=farm.AutoresetMode.NEXT_STEP))


def test_termination_is_not_a_time_limit():
    # The Jetbot's crashes and goals end episodes for good: TimeLimit.truncated is False there.
    venv = SB3VecEnv(farm.make_vec("jetbot", 4, seed=2))
    venv.seed(2)
    venv.reset()
    rng = np.random.default_rng(2)
    seen = 0
    for _ in range(2000):
        _, _, dones, infos = venv.step(rng.integers(7, size=4))
        for i in np.flatnonzero(dones):
            seen += 1
            assert "terminal_observation" in infos[i]
            assert infos[i]["episode"]["l"] < 3000  # before the Jetbot's time limit: a crash or a goal
            assert infos[i]["TimeLimit.truncated"] is False
        if seen >= 4:
            break
    assert seen >= 4


class ReplayBuffer:
    """SB3's ReplayBuffer.add: np.array copies of what it is given, dones masked by
    TimeLimit.truncated (handle_timeout_termination)."""

    def __init__(self, size, n_envs, obs_dim, act_dim):
        rows = size // n_envs
        self.obs = np.zeros((rows, n_envs, obs_dim), np.float32)
        self.next_obs = np.zeros((rows, n_envs, obs_dim), np.float32)
        self.actions = np.zeros((rows, n_envs, act_dim), np.float32)
        self.rewards = np.zeros((rows, n_envs), np.float32)
        self.dones = np.zeros((rows, n_envs), np.float32)
        self.timeouts = np.zeros((rows, n_envs), np.float32)
        self.pos, self.full, self.rows = 0, False, rows

    def add(self, obs, next_obs, action, reward, done, infos):
        self.obs[self.pos] = np.array(obs)
        self.next_obs[self.pos] = np.array(next_obs)
        self.actions[self.pos] = np.array(action)
        self.rewards[self.pos] = np.array(reward)
        self.dones[self.pos] = np.array(done)
        self.timeouts[self.pos] = np.array([info.get("TimeLimit.truncated", False) for info in infos])
        self.pos = (self.pos + 1) % self.rows
        self.full = self.full or self.pos == 0

    def stored(self):
        end = self.rows if self.full else self.pos
        return self.obs[:end].reshape(-1, self.obs.shape[-1]), self.next_obs[:end].reshape(-1, self.obs.shape[-1])

    def sample(self, batch, rng):
        end = self.rows if self.full else self.pos
        r, e = rng.integers(0, end, batch), rng.integers(0, self.obs.shape[1], batch)
        t = [torch.from_numpy(x[r, e]) for x in (self.obs, self.actions, self.rewards, self.next_obs)]
        return t + [torch.from_numpy(self.dones[r, e] * (1 - self.timeouts[r, e]))]


def mlp(sizes):
    layers = []
    for i in range(len(sizes) - 1):
        layers += [nn.Linear(sizes[i], sizes[i + 1]), nn.ReLU()]
    return nn.Sequential(*layers[:-1])


def sample_action(actor, obs, deterministic=False):
    mean, log_std = actor(obs).chunk(2, dim=-1)
    if deterministic:
        return torch.tanh(mean), None
    std = log_std.clamp(-20, 2).exp()
    u = mean + std * torch.randn_like(mean)
    a = torch.tanh(u)
    logp = (-0.5 * ((u - mean) / std) ** 2 - std.log() - 0.5 * np.log(2 * np.pi)).sum(-1)
    return a, logp - torch.log(1 - a.pow(2) + 1e-6).sum(-1)


def evaluate(actor, episodes=10, seed=1000):
    """Deterministic episodes on envs of their own, as the learner's evaluation runs them."""
    env = farm.make_vec("pendulum", episodes, seed=seed)
    obs, _ = env.reset(seed=seed)
    total, done = np.zeros(episodes), np.zeros(episodes, bool)
    while not done.all():
        with torch.no_grad():
            a = sample_action(actor, torch.from_numpy(obs), deterministic=True)[0]
        obs, r, term, trunc, _ = env.step(a)  # a torch tensor: the VecEnv converts it
        total += np.where(done, 0, r)
        done |= term | trunc
    return float(total.mean())


def test_sb3_style_sac_reaches_the_pendulum_target():
    target = pendulum_target()
    torch.manual_seed(1)
    torch.set_num_threads(1)
    rng = np.random.default_rng(1)
    n_envs, learning_starts, batch, gamma, tau = 2, 1000, 256, 0.99, 0.005
    env = SB3VecEnv(farm.make_vec("pendulum", n_envs, seed=1))
    od, ad = env.observation_space.shape[0], env.action_space.shape[0]
    actor = mlp([od, 64, 64, 2 * ad])
    q1, q2, q1_t, q2_t = (mlp([od + ad, 64, 64, 1]) for _ in range(4))
    q1_t.load_state_dict(q1.state_dict())
    q2_t.load_state_dict(q2.state_dict())
    log_alpha = torch.zeros(1, requires_grad=True)
    opt_pi = torch.optim.Adam(actor.parameters(), 1e-3)
    opt_q = torch.optim.Adam(list(q1.parameters()) + list(q2.parameters()), 1e-3)
    opt_alpha = torch.optim.Adam([log_alpha], 1e-3)
    rb = ReplayBuffer(100_000, n_envs, od, ad)
    env.action_space.seed(1)
    env.seed(1)
    last_obs = env.reset()
    best, steps, t0, evaluations = -np.inf, 0, time.monotonic(), []
    while steps < 12_000 and best < target:  # reached by 4,000-8,000 on seeds 1-6
        # collect_rollouts: one step of every env, random actions before learning starts.
        if steps < learning_starts:
            actions = np.stack([env.action_space.sample() for _ in range(n_envs)])
        else:
            with torch.no_grad():
                actions = sample_action(actor, torch.from_numpy(last_obs))[0].numpy()
        env.step_async(actions)
        new_obs, rewards, dones, infos = env.step_wait()
        # _store_transition: the true next observation of an env whose episode ended.
        next_obs = new_obs.copy()
        for i, done in enumerate(dones):
            if done and infos[i].get("terminal_observation") is not None:
                next_obs[i] = infos[i]["terminal_observation"]
        rb.add(last_obs, next_obs, actions, rewards, dones, infos)
        last_obs = new_obs  # kept as is, as SB3 keeps it: the adapter's arrays are the caller's own
        steps += n_envs
        if steps < learning_starts:
            continue
        for _ in range(n_envs):  # gradient_steps: one per env step
            o, a, r, o2, d = rb.sample(batch, rng)
            with torch.no_grad():
                a2, logp2 = sample_action(actor, o2)
                x2 = torch.cat([o2, a2], -1)
                y = r + gamma * (1 - d) * (torch.min(q1_t(x2), q2_t(x2)).squeeze(-1) - log_alpha.exp() * logp2)
            x = torch.cat([o, a], -1)
            loss_q = F.mse_loss(q1(x).squeeze(-1), y) + F.mse_loss(q2(x).squeeze(-1), y)
            opt_q.zero_grad()
            loss_q.backward()
            opt_q.step()
            pi, logp = sample_action(actor, o)
            xp = torch.cat([o, pi], -1)
            loss_pi = (log_alpha.exp().detach() * logp - torch.min(q1(xp), q2(xp)).squeeze(-1)).mean()
            opt_pi.zero_grad()
            loss_pi.backward()
            opt_pi.step()
            loss_alpha = -(log_alpha * (logp.detach() - ad).mean())
            opt_alpha.zero_grad()
            loss_alpha.backward()
            opt_alpha.step()
            with torch.no_grad():
                for net, tgt in ((q1, q1_t), (q2, q2_t)):
                    for p, pt in zip(net.parameters(), tgt.parameters()):
                        pt.mul_(1 - tau).add_(tau * p)
        if steps % 1000 == 0:
            evaluations.append((steps, evaluate(actor)))
            best = max(best, evaluations[-1][1])
    print("SB3-style SAC: %d env steps in %.1f s, evaluations %s" % (steps, time.monotonic() - t0, evaluations))
    assert best >= target, evaluations
    # Every transition stored has its own next observation: the pendulum never repeats a state
    # exactly from one step to the next, so a row with obs == next_obs is one the env overwrote.
    obs, nxt = rb.stored()
    assert len(obs) == steps
    assert int(np.all(obs == nxt, axis=1).sum()) == 0


def test_a_pass_through_of_views_would_store_obs_equal_to_next_obs():
    # What the adapter's copies prevent: the same data path over the VecEnv's views (copy=False) and
    # an adapter that passes them through stores the new observation as the old one.
    env = farm.make_vec("pendulum", 2, seed=3, copy=False)
    last_obs, _ = env.reset(seed=3)
    rb = ReplayBuffer(1000, 2, 3, 1)
    for _ in range(100):
        actions = np.full((2, 1), 0.5, np.float32)
        new_obs, rewards, term, trunc, infos = env.step(actions)
        rb.add(last_obs, new_obs.copy(), actions, rewards, term | trunc, [{}, {}])
        last_obs = new_obs
    obs, nxt = rb.stored()
    assert int(np.all(obs == nxt, axis=1).sum()) >= 198  # all but the first step's rows
