"""One place that builds every environment safe_bc uses, from the task registry."""

from __future__ import annotations

import gymnasium as gym

from safe_bc.envs.config import EnvConfig, EnvId, Renderer
from safe_bc.envs.info import InfoContract

# the built-in tasks' ids, kept importable from here (their home is the task folders)
from safe_bc.tasks.carracing import (
    CARRACING_ID,
    CARRACING_IDS,
    FAST_CARRACING_ID,
    RASTER_CARRACING_ID,
)
from safe_bc.tasks.registry import TASKS, register_envs, spec_of
from safe_bc.tasks.rehab import REHAB_ID

ENV_IDS: tuple[str, ...] = tuple(g.id for spec in TASKS.values() for g in spec.gym_envs)
"""The gymnasium ids that ``import safe_bc`` (or :func:`register_envs`) registers: the
built-in tasks' (a task registered later registers its own)."""

__all__ = [
    "CARRACING_ID",
    "CARRACING_IDS",
    "ENV_IDS",
    "FAST_CARRACING_ID",
    "RASTER_CARRACING_ID",
    "REHAB_ID",
    "EnvConfig",
    "EnvId",
    "Renderer",
    "make_env",
    "register_envs",
]


def make_env(config: EnvConfig | None = None) -> gym.Env:
    """Build the environment of ``config`` (its task's ``make_env``) with safety costs in
    ``info``, the info contract checked on each episode's first steps.

    >>> env = make_env(EnvConfig(renderer="stock", max_episode_steps=60))
    >>> obs, info = env.reset(seed=3)
    >>> obs.shape, sorted(k for k in info if k in ("cost", "safety"))
    ((96, 96, 3), ['cost', 'safety'])
    >>> env.close()
    """
    config = config or EnvConfig()
    try:
        spec = spec_of(config.env_id)
    except ValueError:
        raise ValueError(f"unknown env_id {config.env_id!r}") from None
    register_envs()
    return InfoContract(spec.make_env(config))
