"""The agent's pieces: the Gaussian actor, the critics, GAE and the multiplier step."""

from __future__ import annotations

import math
from dataclasses import asdict

import numpy as np
import torch
from torch import nn

from safe_bc.bc.config import NetworkConfig
from safe_bc.bc.net import BCNet, ModelSpec


def multiplier_update(
    lam: float, episode_cost: float, budget: float, lr: float, lam_max: float = math.inf
) -> float:
    """One projected gradient-ascent step of the Lagrange multiplier.

    ``lambda <- clip(lambda + lr * (J_c - budget), 0, lam_max)``: it rises while the
    episodes' mean cost ``J_c`` exceeds the budget and falls (never below 0) otherwise.

    >>> multiplier_update(1.0, 0.5, 0.1, 1.0), multiplier_update(0.1, 0.0, 0.5, 1.0)
    (1.4, 0.0)
    """
    return float(min(max(lam + lr * (episode_cost - budget), 0.0), lam_max))


def gae(
    rewards: np.ndarray, values: np.ndarray, last_value: float, gamma: float, lam: float
) -> tuple[np.ndarray, np.ndarray]:
    """Advantages and returns of one episode (``last_value``: 0 when it terminated).

    >>> adv, ret = gae(np.ones(2), np.zeros(2), 0.0, 1.0, 1.0)
    >>> adv.tolist(), ret.tolist()
    ([2.0, 1.0], [2.0, 1.0])
    """
    adv = np.zeros(len(rewards))
    running = 0.0
    for t in reversed(range(len(rewards))):
        next_value = values[t + 1] if t + 1 < len(rewards) else last_value
        delta = rewards[t] + gamma * next_value - values[t]
        running = delta + gamma * lam * running
        adv[t] = running
    return adv, adv + values


# --------------------------------------------------------------------------- the agent
class GaussianActor(nn.Module):
    """``N(mean_net(x), exp(log_std))``: the BC net as the mean, a learned state-free std."""

    def __init__(self, mean_net: BCNet, init_std: float) -> None:
        super().__init__()
        self.mean_net = mean_net
        self.log_std = nn.Parameter(torch.full((mean_net.spec.action_dim,), math.log(init_std)))

    def dist(self, x: torch.Tensor) -> torch.distributions.Normal:
        mean = self.mean_net(x)
        return torch.distributions.Normal(mean, self.log_std.exp().expand_as(mean))


def make_critic(actor_net: BCNet, hidden: int) -> BCNet:
    """A value net: the BC net's body and depth, ``hidden`` wide, one unbounded output, the
    same input standardisation."""
    spec = ModelSpec(actor_net.spec.obs_shape, (-math.inf,), (math.inf,))
    net_cfg = NetworkConfig(**{**asdict(actor_net.net_cfg), "hidden": hidden})
    critic = BCNet(spec, actor_net.pre_cfg, net_cfg)
    if critic.vector_input:
        critic.obs_mean.copy_(actor_net.obs_mean)
        critic.obs_std.copy_(actor_net.obs_std)
    return critic
