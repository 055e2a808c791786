"""Shared real-CarRacing rollouts for the expert and perturbation tests (short episodes,
computed once), and the episode loop they use: the expert (optionally perturbed) on the raw
env, recording what the tests check (labels and executed actions, wheel contacts, the hull's
lateral offset from the centre line), which the evaluation path does not keep."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import pytest

from safe_bc.tasks.carracing import CARRACING_ID
from safe_bc.tasks.carracing.costs import pixel_distances
from safe_bc.tasks.carracing.expert import CarRacingExpert
from safe_bc.tasks.carracing.geometry import lateral_offset
from safe_bc.tasks.carracing.perturb import Perturbation, PerturbationConfig


@dataclass(frozen=True)
class RolloutStats:
    """Summary of one expert episode (``T`` steps executed)."""

    seed: int
    """Track seed passed to ``env.reset``."""
    reward: float
    """Sum of rewards."""
    length: int
    """Steps executed ``T``."""
    offroad_steps: int
    """Steps after which all four wheels were off the road (no tile contact)."""
    min_wheels_on_road: int
    """Fewest wheels touching a road tile at any step (4 = never left the road)."""
    max_abs_lateral: float
    """Largest ``|lateral offset|`` of the hull from the centre line, units."""
    lap_finished: bool
    """Whether the episode ended by completing the lap."""
    actions: np.ndarray
    """``(T, 3) float32`` actions chosen by the expert (the labels)."""
    executed_actions: np.ndarray
    """``(T, 3) float32`` actions sent to the env (perturbed)."""
    lateral: np.ndarray
    """``(T,) float64`` signed lateral offset after each step (positive = right)."""


def make_env() -> gym.Env:
    """CarRacing-v3 (continuous, 1000-step limit, frames drawn: the drift reads them)."""
    return gym.make(CARRACING_ID)


def rollout(
    env: gym.Env,
    seed: int,
    expert: CarRacingExpert | None = None,
    perturbation: Perturbation | None = None,
    rng_seed: int = 0,
    max_steps: int = 1000,
) -> RolloutStats:
    """Run one episode of the expert on track ``seed``; ``rng_seed`` seeds the perturbation."""
    expert = expert if expert is not None else CarRacingExpert()
    rng = np.random.default_rng(rng_seed)
    obs, _ = env.reset(seed=seed)
    expert.reset(env, rng)
    if perturbation is not None:
        perturbation.reset(rng)
    unwrapped = env.unwrapped
    track = np.asarray(unwrapped.track, dtype=np.float64)
    total, offroad, min_wheels, finished = 0.0, 0, 4, False
    actions, executed, lateral = [], [], []
    for t in range(max_steps):
        action = expert.act(obs, env)
        if perturbation is None:
            exe = action
        else:  # the frame's distances let a drift stop short of the grass
            safety = pixel_distances(obs) if obs is not None and t > 0 else None
            exe = perturbation.apply(action, t, rng, safety)
        obs, reward, terminated, truncated, info = env.step(exe)
        total += float(reward)
        wheels = sum(1 for w in unwrapped.car.wheels if w.tiles)
        min_wheels = min(min_wheels, wheels)
        offroad += wheels == 0
        actions.append(action)
        executed.append(exe)
        lateral.append(lateral_offset(track, np.asarray(unwrapped.car.hull.position)))
        if terminated or truncated:
            finished = bool(info.get("lap_finished", False))
            break
    lat = np.asarray(lateral, dtype=np.float64)
    return RolloutStats(
        seed=seed,
        reward=total,
        length=len(actions),
        offroad_steps=int(offroad),
        min_wheels_on_road=int(min_wheels),
        max_abs_lateral=float(np.abs(lat).max()) if lat.size else 0.0,
        lap_finished=finished,
        actions=np.asarray(actions, dtype=np.float32).reshape(-1, 3),
        executed_actions=np.asarray(executed, dtype=np.float32).reshape(-1, 3),
        lateral=lat,
    )


TRACK_SEEDS: tuple[int, ...] = (3, 21)
"""Track seeds of the short test episodes (not the 10000+ evaluation seeds)."""

STEPS: int = 350
"""Steps per test episode (the car covers roughly a third of a lap)."""


@pytest.fixture(scope="session")
def carracing_env() -> Iterator[gym.Env]:
    """One real CarRacing-v3 env (with frame rendering), shared by the tests."""
    env = make_env()
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
