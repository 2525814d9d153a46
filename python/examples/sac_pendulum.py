#!/usr/bin/env python3
"""SAC in PyTorch, trained from the farm's C++ workers over DDS.

  farm-worker --domain 7 &  farm-worker --domain 7 &
  PYTHONPATH=build/python python3 python/examples/sac_pendulum.py deploy/configs/pendulum_sac.txtpb --domain 7

The workers collect with the published policy; batches arrive checked and accounted by the
learner's C++ ingest; every few seconds the deterministic policy is evaluated on local envs
(farm.make_vec). It stops at the target return or the time limit, has a worker evaluate the final
policy, and prints one JSON line.
"""
import argparse
import json
import time

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

import farm
from farm.torch_policy import policy_params

LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0  # the workers clamp log_std to these (PolicyParams)


def mlp(sizes):
    layers = []
    for i in range(len(sizes) - 1):
        layers += [nn.Linear(sizes[i], sizes[i + 1]), nn.ReLU()]
    return nn.Sequential(*layers[:-1])


class Replay:
    def __init__(self, size, od, ad):
        self.o, self.a = np.zeros((size, od), np.float32), np.zeros((size, ad), np.float32)
        self.r, self.o2 = np.zeros(size, np.float32), np.zeros((size, od), np.float32)
        self.d, self.n, self.i, self.size = np.zeros(size, np.float32), 0, 0, size

    def add(self, b):
        for k in range(len(b["rewards"])):  # row by row keeps the ring simple; batches are small
            j = self.i
            self.o[j], self.a[j], self.r[j] = b["obs"][k], b["actions"][k], b["rewards"][k]
            self.o2[j], self.d[j] = b["next_obs"][k], float(b["terminated"][k])
            self.i, self.n = (j + 1) % self.size, min(self.n + 1, self.size)

    def sample(self, batch):
        j = np.random.randint(0, self.n, batch)
        return [torch.from_numpy(x[j]) for x in (self.o, self.a, self.r, self.o2, self.d)]


def act(actor, obs, deterministic=False):
    out = actor(obs)
    mean, log_std = out.chunk(2, dim=-1)
    if deterministic:
        return torch.tanh(mean), None
    std = log_std.clamp(LOG_STD_MIN, LOG_STD_MAX).exp()
    u = mean + std * torch.randn_like(mean)
    a = torch.tanh(u)
    logp = (-0.5 * ((u - mean) / std) ** 2 - std.log() - 0.5 * np.log(2 * np.pi)).sum(-1)
    return a, logp - torch.log(1 - a.pow(2) + 1e-6).sum(-1)


def evaluate(actor, task, episodes=10, seed=1000):
    env = farm.make_vec(task, episodes, seed=seed)
    obs, _ = env.reset(seed=seed)
    total, done = np.zeros(episodes), np.zeros(episodes, bool)
    while not done.all():
        with torch.no_grad():
            a = act(actor, torch.from_numpy(obs.copy()), deterministic=True)[0].numpy()
        obs, r, term, trunc, _ = env.step(a.astype(np.float32))
        total += np.where(done, 0, r)
        done |= term | trunc
    return float(total.mean())


def main():
    ap = argparse.ArgumentParser(description="SAC in PyTorch over the farm's C++ workers")
    ap.add_argument("config")
    ap.add_argument("--domain", type=int, default=0)
    ap.add_argument("--profiles", default="")
    ap.add_argument("--target", type=float, default=-200.0)
    ap.add_argument("--max-seconds", type=float, default=300.0)
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    torch.manual_seed(a.seed)
    np.random.seed(a.seed)
    torch.set_num_threads(1)
    bus = farm.LearnerBus(a.config, domain=a.domain, profiles=a.profiles)
    od, ad = bus.obs_dim, bus.act_dim
    actor, q1, q2 = mlp([od, 64, 64, 2 * ad]), mlp([od + ad, 64, 64, 1]), mlp([od + ad, 64, 64, 1])
    q1_t, q2_t = mlp([od + ad, 64, 64, 1]), mlp([od + ad, 64, 64, 1])
    q1_t.load_state_dict(q1.state_dict())
    q2_t.load_state_dict(q2.state_dict())
    log_alpha = torch.zeros(1, requires_grad=True)
    opt_pi = torch.optim.Adam(actor.parameters(), 1e-3)
    opt_q = torch.optim.Adam(list(q1.parameters()) + list(q2.parameters()), 1e-3)
    opt_alpha = torch.optim.Adam([log_alpha], 1e-3)
    replay, gamma, tau, version, updates = Replay(200000, od, ad), 0.99, 0.005, 1, 0
    bus.publish(policy_params(actor, version))
    t0, last_eval, best = time.time(), time.time(), -np.inf
    while time.time() - t0 < a.max_seconds:
        got = bus.take(max_batches=64, timeout=0.01 if replay.n >= 1000 else 0.1)
        for b in got:
            replay.add(b)
        if replay.n < 1000:  # learning starts: more of the first policy, under a new version each time
            if got:
                version += 1
                bus.publish(policy_params(actor, version))
            continue
        for _ in range(25):  # then publish: the workers make max_batches_per_version per version
            o, ac, r, o2, d = replay.sample(256)
            with torch.no_grad():
                a2, logp2 = act(actor, o2)
                x2 = torch.cat([o2, a2], -1)
                y = r + gamma * (1 - d) * (torch.min(q1_t(x2), q2_t(x2)).squeeze(-1) - log_alpha.exp() * logp2)
            x = torch.cat([o, ac], -1)
            loss_q = F.mse_loss(q1(x).squeeze(-1), y) + F.mse_loss(q2(x).squeeze(-1), y)
            opt_q.zero_grad()
            loss_q.backward()
            opt_q.step()
            pi, logp = act(actor, o)
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
            updates += 1
        version += 1
        bus.publish(policy_params(actor, version))
        if time.time() - last_eval >= 5:
            last_eval = time.time()
            best = max(best, evaluate(actor, "pendulum"))
            c = bus.counters()
            print("%6.1f s  env steps %d  updates %d  eval %.1f" % (time.time() - t0, c["env_steps"], updates, best),
                  flush=True)
            if best >= a.target:
                break
    seconds = time.time() - t0
    # The final policy evaluated on a worker, by the workers' own code: 10 deterministic episodes.
    answer = bus.evaluate(policy_params(actor, version), episodes=10, timeout=60)
    bus.finish()
    c = bus.counters()
    print(json.dumps({"reached": best >= a.target, "eval_return": best, "seconds": seconds,
                      "worker_eval_return": float(answer["returns"].mean()), "worker": answer["worker_id"],
                      "updates": updates, "env_steps": c["env_steps"], "batches_ok": c["batches_ok"],
                      "batches_lost": c["batches_lost"], "batches_invalid": c["batches_invalid"]}), flush=True)
    return 0 if best >= a.target else 1


if __name__ == "__main__":
    raise SystemExit(main())
