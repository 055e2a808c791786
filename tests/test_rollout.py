"""Episodes in lockstep (several envs, one batched policy call per step) against one by one."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

from safe_bc.bc import (
    CAR_RACING_BOUNDS,
    BCNet,
    BCPolicy,
    ModelSpec,
    NetworkConfig,
    PreprocessConfig,
)
from safe_bc.rollout.episode import run_episode, run_episodes_lockstep
from safe_bc.tasks import make_env


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


def _episodes_equal(a, b) -> bool:
    fields = ("actions", "executed_actions", "rewards", "terminated", "truncated", "safety",
              "costs", "warmup", "offroad", "observations")  # fmt: skip
    return all(np.array_equal(getattr(a, f), getattr(b, f)) for f in fields)


def test_batched_lockstep_gives_the_same_episodes_again_on_this_machine():
    """forward="batched" (one forward pass over the running envs): two runs with the same
    seeds and envs give the same episodes, the batch shrinking mid-run as well. Nothing is
    claimed against the one-env episodes (a batched pass may round differently)."""
    torch.manual_seed(1)
    spec = ModelSpec.for_data((96, 96, 3), 3, CAR_RACING_BOUNDS)
    model = BCNet(spec, PreprocessConfig(), NetworkConfig()).eval()  # the default net
    limits, seeds = (70, 40, 70), [21, 22, 23]
    envs = [gym.wrappers.TimeLimit(make_env(), n) for n in limits]
    runs = [
        run_episodes_lockstep(envs, BCPolicy(model), seeds, forward="batched") for _ in range(2)
    ]
    assert [len(ep) for ep in runs[0]] == list(limits)
    for first, again in zip(*runs, strict=True):
        assert _episodes_equal(first, again)
    for env in envs:
        env.close()


def test_a_bad_lockstep_forward_is_one_clear_line():
    from safe_bc.rollout.evaluate import EvalConfig

    torch.manual_seed(0)
    spec = ModelSpec.for_data((96, 96, 3), 3, CAR_RACING_BOUNDS)
    policy = BCPolicy(BCNet(spec, PreprocessConfig(), NetworkConfig(hidden=16)).eval())
    policy.reset_slots(1)
    frames = np.zeros((1, 96, 96, 3), np.uint8)
    calls = [
        lambda: EvalConfig(lockstep_forward="batch"),  # type: ignore[arg-type]
        lambda: run_episodes_lockstep([], policy, [], forward="batch"),  # type: ignore[arg-type]
        lambda: policy.act_slots(frames, np.arange(1), "batch"),  # type: ignore[arg-type]
    ]
    for call in calls:
        with pytest.raises(ValueError) as err:
            call()
        assert len(str(err.value).splitlines()) == 1
        assert "must be one of rows, batched, got 'batch'" in str(err.value)
