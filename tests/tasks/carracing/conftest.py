"""Shared real-CarRacing rollouts for the expert tests (short episodes, computed once)."""

from __future__ import annotations

from collections.abc import Iterator

import gymnasium as gym
import pytest

from safe_bc.tasks.carracing.expert import CarRacingExpert
from safe_bc.tasks.carracing.perturb import Perturbation, PerturbationConfig
from scripts.evaluate_expert import RolloutStats, make_env, rollout

TRACK_SEEDS: tuple[int, ...] = (3, 21)
"""Track seeds of the short test episodes (not the 10000+ evaluation seeds)."""

STEPS: int = 350
"""Steps per test episode (the car covers roughly a third of a lap)."""


@pytest.fixture(scope="session")
def carracing_env() -> Iterator[gym.Env]:
    """One real CarRacing-v3 env (with frame rendering), shared by the tests."""
    env = make_env(render=True)
    yield env
    env.close()


@pytest.fixture(scope="session")
def unperturbed_rollouts(carracing_env: gym.Env) -> list[RolloutStats]:
    """Default expert, no perturbation, on each of ``TRACK_SEEDS``."""
    return [
        rollout(carracing_env, seed, CarRacingExpert(), None, max_steps=STEPS)
        for seed in TRACK_SEEDS
    ]


@pytest.fixture(scope="session")
def drift_rollouts(carracing_env: gym.Env) -> list[RolloutStats]:
    """Default expert under the default (drift) perturbation, on each of ``TRACK_SEEDS``."""
    return [
        rollout(
            carracing_env,
            seed,
            CarRacingExpert(),
            Perturbation(PerturbationConfig()),
            rng_seed=k,
            max_steps=STEPS,
        )
        for k, seed in enumerate(TRACK_SEEDS)
    ]
