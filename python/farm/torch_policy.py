"""PyTorch networks in the workers' policy layout, and back.

The workers run a policy as an MLP of Linear layers with one hidden activation (ReLU, Tanh or ELU)
and a head: a squashed Gaussian (SAC: the output is [mean, log_std], the action tanh of a sample),
a Gaussian (PPO: the output is the mean, log_std a separate parameter), or a discrete Q head (DQN:
the greedy action). ``policy_params`` turns an ``nn.Sequential`` into the dict that
``LearnerBus.publish`` takes; ``sequential`` rebuilds the network from such a dict or from
``farm.load_policy(...).params()``.
"""
import numpy as np
import torch
from torch import nn

ACTIVATIONS = {nn.ReLU: 0, nn.Tanh: 1, nn.ELU: 2}
HEADS = {"squashed_gaussian": 0, "gaussian": 1, "discrete_q": 2}


def policy_params(net, version, head="squashed_gaussian", log_std=None, obs_mean=None, obs_std=None,
                  epsilon=None):
    """The workers' layout of ``net``: Linear, activation, Linear, ..., Linear (one activation kind,
    none after the last layer, every Linear with its bias). Raises ValueError naming the layer that
    does not fit. ``epsilon``: for the "discrete_q" head, the probability in [0, 1] with which the
    workers take a uniformly random action while they collect (DQN's exploration; 0 by default)."""
    if head not in HEADS:
        raise ValueError("head: expected one of %s, got %r" % (sorted(HEADS), head))
    if (obs_mean is None) != (obs_std is None):
        raise ValueError("obs_mean and obs_std: give both or neither")
    if epsilon is not None and head != "discrete_q":
        raise ValueError("epsilon: only for the discrete_q head, not %r" % head)
    layers = list(net)
    linears, acts = layers[0::2], layers[1::2]
    for i, layer in enumerate(linears):
        if not isinstance(layer, nn.Linear):
            raise ValueError("layer %d: expected nn.Linear, got %s" % (2 * i, type(layer).__name__))
        if layer.bias is None:
            raise ValueError("layer %d: an nn.Linear without bias; the workers' layout has one on every layer"
                             % (2 * i))
    kinds = {type(a) for a in acts}
    if len(linears) != len(acts) + 1 or len(kinds) > 1 or not kinds <= set(ACTIVATIONS):
        raise ValueError("expected Linear layers with one activation of %s between them, got %s" % (
            [a.__name__ for a in ACTIVATIONS], [type(l).__name__ for l in layers]))
    sizes = [linears[0].in_features] + [l.out_features for l in linears]
    flat = []
    with torch.no_grad():
        for l in linears:
            flat.append(l.weight.detach().cpu().float().reshape(-1))
            flat.append(l.bias.detach().cpu().float().reshape(-1))
    p = {"version": int(version), "sizes": sizes, "activation": ACTIVATIONS[kinds.pop()] if kinds else 0,
         "head": HEADS[head], "params": torch.cat(flat).numpy().astype(np.float32)}
    if log_std is not None:
        p["log_std"] = [float(x) for x in torch.as_tensor(log_std).reshape(-1)]
    if obs_mean is not None:
        p["obs_mean"] = [float(x) for x in np.asarray(obs_mean).reshape(-1)]
        p["obs_std"] = [float(x) for x in np.asarray(obs_std).reshape(-1)]
    if epsilon is not None:
        p["epsilon"] = float(epsilon)
    return p


def sequential(params):
    """The nn.Sequential of a policy's layout (a dict of ``policy_params`` or ``Policy.params()``);
    the normalizer and head stay with the caller."""
    sizes, flat = params["sizes"], np.asarray(params["params"], dtype=np.float32)
    act = {v: k for k, v in ACTIVATIONS.items()}[params.get("activation", 0)]
    layers, k = [], 0
    for i in range(len(sizes) - 1):
        lin = nn.Linear(sizes[i], sizes[i + 1])
        w = sizes[i + 1] * sizes[i]
        with torch.no_grad():
            lin.weight.copy_(torch.from_numpy(flat[k:k + w].reshape(sizes[i + 1], sizes[i])))
            lin.bias.copy_(torch.from_numpy(flat[k + w:k + w + sizes[i + 1]]))
        k += w + sizes[i + 1]
        layers.append(lin)
        if i < len(sizes) - 2:
            layers.append(act())
    if k != len(flat):
        raise ValueError("params: %d numbers for sizes %s, which take %d" % (len(flat), sizes, k))
    return nn.Sequential(*layers)
