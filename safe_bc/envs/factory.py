"""One place that builds every environment safe_bc uses."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

import gymnasium as gym

from safe_bc.envs.wrappers import CarRacingSafety

EnvId = Literal["CarRacing-v3", "safe_bc/RehabPathway-v0"]
"""The envs a task can name (``safe_bc.tasks`` pairs each with its task)."""
CARRACING_ID, REHAB_ID = get_args(EnvId)
Renderer = Literal["fast", "stock", "raster"]
"""CarRacing renderers: ``fast`` (default) and ``stock`` draw identical frames; ``raster`` draws
approximate ones faster (opt-in, measured in ``results/ablation/renderer/``)."""

FAST_CARRACING_ID = "safe_bc/CarRacingFast-v3"
RASTER_CARRACING_ID = "safe_bc/CarRacingRaster-v3"
ENV_IDS: tuple[str, ...] = (FAST_CARRACING_ID, RASTER_CARRACING_ID, REHAB_ID)
"""The gymnasium ids that ``import safe_bc`` (or :func:`register_envs`) registers."""


@dataclass(frozen=True)
class EnvConfig:
    """Which environment to build, and how."""

    env_id: EnvId = CARRACING_ID
    """The task: the CarRacing testbed or the rehabilitation pathway."""
    renderer: Renderer = "fast"
    """CarRacing only: ``"fast"`` draws pixel-identical frames faster, ``"stock"`` is
    gymnasium's own renderer, ``"raster"`` rasterises approximate frames directly at 96x96
    (faster still; frames and costs differ from stock at edges: no committed result uses it)."""
    max_episode_steps: int | None = None
    """Time limit; ``None`` keeps the env's own (1000 steps for CarRacing)."""

    def __post_init__(self) -> None:
        if self.env_id not in get_args(EnvId):
            raise ValueError(f"unknown env_id {self.env_id!r}")
        if self.renderer not in get_args(Renderer):
            raise ValueError(f"renderer must be one of {get_args(Renderer)}, got {self.renderer!r}")
        if self.max_episode_steps is not None and self.max_episode_steps < 1:
            raise ValueError(f"max_episode_steps must be >= 1, got {self.max_episode_steps}")

    @property
    def is_carracing(self) -> bool:
        """True for the pixel-based CarRacing testbed."""
        return self.env_id == CARRACING_ID


CARRACING_IDS: dict[Renderer, str] = {
    "fast": FAST_CARRACING_ID,
    "raster": RASTER_CARRACING_ID,
    "stock": CARRACING_ID,
}
"""The gymnasium id that each renderer's CarRacing is made from."""
_CARRACING_ENTRY_POINTS = {
    FAST_CARRACING_ID: "safe_bc.envs.fast_render:FastCarRacing",
    RASTER_CARRACING_ID: "safe_bc.envs.raster_render:RasterCarRacing",
}


def register_envs() -> None:
    """Register safe_bc's environment ids, :data:`ENV_IDS`, with gymnasium (idempotent).

    ``import safe_bc`` calls this, so ``gym.make("safe_bc/RehabPathway-v0")`` works after
    the import and ``gym.make("safe_bc:safe_bc/RehabPathway-v0")`` works without it.
    Entry points are strings: nothing heavier than gymnasium is imported here.

    >>> register_envs(); all(env_id in gym.registry for env_id in ENV_IDS)
    True
    """
    for env_id, entry_point in _CARRACING_ENTRY_POINTS.items():
        if env_id not in gym.registry:
            gym.register(
                id=env_id, entry_point=entry_point, max_episode_steps=1000, reward_threshold=900
            )
    if REHAB_ID not in gym.registry:
        from safe_bc.envs.rehab import DEFAULT_N_SESSIONS

        gym.register(
            id=REHAB_ID,
            entry_point="safe_bc.envs.rehab:RehabPathwayEnv",
            max_episode_steps=DEFAULT_N_SESSIONS,
        )


def make_env(config: EnvConfig | None = None) -> gym.Env:
    """Build the environment of ``config`` with safety costs in ``info``.

    >>> env = make_env(EnvConfig(renderer="stock", max_episode_steps=60))
    >>> obs, info = env.reset(seed=3)
    >>> obs.shape, sorted(k for k in info if k in ("cost", "safety"))
    ((96, 96, 3), ['cost', 'safety'])
    >>> env.close()
    """
    config = config or EnvConfig()
    register_envs()
    kwargs = {}
    if config.max_episode_steps is not None:
        kwargs["max_episode_steps"] = config.max_episode_steps
    if config.is_carracing:
        env = gym.make(
            CARRACING_IDS[config.renderer], continuous=True, domain_randomize=False, **kwargs
        )
        return CarRacingSafety(env)
    return gym.make(config.env_id, **kwargs)
