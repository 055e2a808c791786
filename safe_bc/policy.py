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
