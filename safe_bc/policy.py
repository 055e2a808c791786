"""The policy protocol shared by experts and learned agents."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import gymnasium as gym
import numpy as np


@runtime_checkable
class Policy(Protocol):
    """Anything that picks actions in an episode.

    Privileged experts read ``env.unwrapped`` (track, car state); learned
    policies use ``obs`` only.
    """

    def reset(self, env: gym.Env, rng: np.random.Generator) -> None:
        """Start a new episode; called after ``env.reset``."""

    def act(self, obs: np.ndarray, env: gym.Env) -> np.ndarray:
        """Return the action for ``obs``, shape ``(A,) float32``."""


@runtime_checkable
class BatchPolicy(Protocol):
    """A policy that acts for several episodes at once (one per slot), each as ``act`` would
    in its own episode: the lockstep evaluation's batched path (observations only)."""

    def reset_slots(self, n: int) -> None:
        """Start ``n`` new episodes, slots ``0 .. n-1``."""

    def act_slots(self, obs: np.ndarray, slots: np.ndarray) -> np.ndarray:
        """Observations ``(m, *obs_shape)`` of the episodes in ``slots`` ``(m,)`` -> actions
        ``(m, A) float32``, each equal to what ``act`` would return in its episode."""
