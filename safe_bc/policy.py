"""The policy protocol shared by experts and learned agents."""

from __future__ import annotations

from typing import Literal, Protocol, get_args, runtime_checkable

import gymnasium as gym
import numpy as np

LockstepForward = Literal["rows", "batched"]
"""How a :class:`BatchPolicy` (a BC net) feeds the observations of envs stepped in lockstep to
its network, one step at a time:

- ``"rows"``: one forward pass per env (``BCNet.forward_rows``). Every episode is, bit for bit,
  the one the one-env path (``act``) gives on the same machine, on any CPU, by construction:
  the same one-row computations run.
- ``"batched"``: one forward pass over all the envs still running (``BCNet.forward``). Faster
  per frame, but a batched pass may round differently from one-row passes (torch, oneDNN and
  MKL pick GEMM/conv kernels by shape and by the CPU's instruction set; on real frames 13-73
  of 360 action elements differed on both AMD and Intel machines:
  ``results/checks/machine_types.md``, ``scripts/batch_rounding.py``), and a different
  last bit of an action changes the rest of the episode. Claimed only: the same seeds and
  the same number of lockstep envs give the same episodes again on the same machine type and
  torch threads; not the one-env path's episodes, and not another CPU's.
"""

LOCKSTEP_FORWARDS: tuple[str, ...] = get_args(LockstepForward)
"""The values of :data:`LockstepForward`."""


def check_lockstep_forward(value: object, name: str = "lockstep_forward") -> None:
    """Raise one ``ValueError`` line unless ``value`` is a :data:`LockstepForward`."""
    if value not in LOCKSTEP_FORWARDS:
        raise ValueError(f"{name} must be one of {', '.join(LOCKSTEP_FORWARDS)}, got {value!r}")


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
    """A policy that acts for several episodes at once (one per slot): the lockstep
    evaluation's path (observations only)."""

    def reset_slots(self, n: int) -> None:
        """Start ``n`` new episodes, slots ``0 .. n-1``."""

    def act_slots(
        self, obs: np.ndarray, slots: np.ndarray, forward: LockstepForward = "rows"
    ) -> np.ndarray:
        """Observations ``(m, *obs_shape)`` of the episodes in ``slots`` ``(m,)`` -> actions
        ``(m, A) float32``. With ``forward="rows"`` each is what ``act`` would return in its
        episode; ``"batched"`` may differ in the last bits (:data:`LockstepForward`)."""
