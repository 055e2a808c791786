"""One place that builds every environment safe_bc uses, from the task registry."""

from __future__ import annotations

import gymnasium as gym

from safe_bc.tasks.env_config import EnvConfig
from safe_bc.tasks.info import InfoContract
from safe_bc.tasks.registry import register_envs, spec_of


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
