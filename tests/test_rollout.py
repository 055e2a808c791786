"""Episodes in lockstep (several envs, one batched policy call per step) against one by one."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch

from safe_bc.bc import (
    CAR_RACING_BOUNDS,
    BCNet,
    BCPolicy,
    ModelSpec,
    NetworkConfig,
    PreprocessConfig,
)
from safe_bc.envs import make_env
from safe_bc.rollout import run_episode, run_episodes_lockstep


def test_lockstep_episodes_of_different_lengths_are_the_one_env_episodes():
    """Real CarRacing; the second env's episode ends first (a shorter time limit), so the
    batch shrinks mid-run."""
    torch.manual_seed(0)
    spec = ModelSpec.for_data((96, 96, 3), 3, CAR_RACING_BOUNDS)
    model = BCNet(spec, PreprocessConfig(), NetworkConfig(hidden=16)).eval()
    limits = (45, 30, 45)
    envs = [gym.wrappers.TimeLimit(make_env(), n) for n in limits]
    seeds = [11, 12, 13]
    together = run_episodes_lockstep(envs, BCPolicy(model), seeds)
    assert [len(ep) for ep in together] == list(limits)
    for env, seed, ep in zip(envs, seeds, together, strict=True):
        alone = run_episode(
            env, BCPolicy(model), seed, np.random.default_rng(seed), keep_observations=False
        )
        for field in ("actions", "executed_actions", "rewards", "terminated", "truncated",
                      "safety", "costs", "warmup", "offroad", "observations"):  # fmt: skip
            np.testing.assert_array_equal(getattr(ep, field), getattr(alone, field), field)
        assert ep.safety_dims == alone.safety_dims and ep.seed == alone.seed
    for env in envs:
        env.close()
