"""The rollout envs (:class:`EnvGroup`, :class:`LocalEnvs`), their seeds and the rollouts."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from safe_bc.methods.improve.config import (
    _TRAIN_SEEDS_PER_RUN,
    TRAIN_SEED_BASE,
    VALIDATION_SEED_BASE,
)
from safe_bc.seeds import HELDOUT_OFFSET


def train_env_seed(seed: int, k: int) -> int:
    """Env seed of training episode ``k`` of run ``seed`` (see :data:`TRAIN_SEED_BASE`)."""
    if not 0 <= k < _TRAIN_SEEDS_PER_RUN:
        raise ValueError(f"training episode index {k} out of range")
    s = TRAIN_SEED_BASE + seed * _TRAIN_SEEDS_PER_RUN + k
    if s >= HELDOUT_OFFSET:
        raise ValueError(f"seed {seed} too large: training seeds must stay below 2**30")
    return s


def validation_seeds(n: int) -> list[int]:
    """The ``n`` validation patients of every run."""
    return [VALIDATION_SEED_BASE - k for k in range(n)]


# --------------------------------------------------------------------------- the envs
StepOut = tuple[np.ndarray, float, bool, bool, np.ndarray]
"""One env step: ``(next_obs, reward, terminated, truncated, cost)``, ``cost`` of shape
``(S,)`` (the env's ``info["cost"]``, the true costs of ``next_obs``; zero on warm-up
frames, :func:`step_cost`)."""


def step_cost(info: dict) -> np.ndarray:
    """The costs a step is charged: ``info["cost"]``, or zeros while ``info["warmup"]`` (the
    CarRacing zoom-in, whose pixel distances are not the road's: the evaluation path does not
    score those frames either, so neither do the Lagrangian's cost, the violation counts nor
    the validation that picks the kept iteration).

    >>> step_cost({"cost": [50.0, 1.0], "warmup": True}).tolist(), step_cost({"cost": [2.0]})
    ([0.0, 0.0], array([2.]))
    """
    cost = np.asarray(info["cost"], np.float64)
    return np.zeros_like(cost) if info.get("warmup", False) else cost


class EnvsLostError(RuntimeError):
    """An env group lost envs mid-episode (a worker died); the episodes must be run again."""


class EnvGroup(Protocol):
    """The ``n`` envs the learner steps in lockstep; where they run is the group's business.

    The learner picks every action (one batched forward pass, its own noise), so a group
    changes where envs step, never what happens: any group gives bit-identical runs.
    """

    def __len__(self) -> int:
        """Number of envs."""

    def reset(self, seeds: Sequence[int]) -> list[np.ndarray]:
        """Reset env ``i`` with ``seeds[i]`` for ``i < len(seeds)``; their first observations."""

    def step(self, index: Sequence[int], actions: np.ndarray) -> list[StepOut]:
        """Step env ``index[j]`` with ``actions[j]`` (``(len(index), A)``), in that order."""

    def restart(self) -> None:
        """Replace lost envs (after :class:`EnvsLostError`); their episodes start over."""

    def close(self) -> None:
        """Release the envs."""


EnvGroupFactory = Callable[[str, int], EnvGroup]
"""``(env_id, n) -> EnvGroup``: how a run gets its envs (:class:`LocalEnvs` by default;
:class:`safe_bc.distributed.envs.RayEnvs` spreads them over Ray actors)."""


class LocalEnvs:
    """``n`` envs in this process (:func:`safe_bc.tasks.make_env`)."""

    def __init__(self, env_id: str, n: int) -> None:
        from safe_bc.tasks import make_env
        from safe_bc.tasks.env_config import EnvConfig

        self.envs = [make_env(EnvConfig(env_id)) for _ in range(n)]

    def __len__(self) -> int:
        return len(self.envs)

    def reset(self, seeds: Sequence[int]) -> list[np.ndarray]:
        if len(seeds) > len(self.envs):
            raise ValueError(f"{len(seeds)} seeds for {len(self.envs)} envs")
        return [env.reset(seed=int(s))[0] for env, s in zip(self.envs, seeds, strict=False)]

    def step(self, index: Sequence[int], actions: np.ndarray) -> list[StepOut]:
        out = []
        for i, a in zip(index, actions, strict=True):
            nobs, r, term, trunc, info = self.envs[i].step(a)
            out.append((nobs, float(r), bool(term), bool(trunc), step_cost(info)))
        return out

    def restart(self) -> None:
        """Nothing is ever lost in-process."""

    def close(self) -> None:
        for env in self.envs:
            env.close()


@dataclass
class Rollout:
    """Complete episodes, flattened in episode order (one row per step)."""

    obs: np.ndarray
    actions: np.ndarray
    logp: np.ndarray
    shielded: np.ndarray
    rewards: np.ndarray
    costs: np.ndarray
    violation: np.ndarray
    adv_r: np.ndarray
    ret_r: np.ndarray
    adv_c: np.ndarray
    ret_c: np.ndarray
    episode_return: np.ndarray
    episode_cost: np.ndarray
    episode_violations: np.ndarray

    def __len__(self) -> int:
        return len(self.rewards)
