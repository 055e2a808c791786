"""Which environment to build, and how (a frozen record; nothing is built here)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

EnvId = str
"""The env id a task registers (``safe_bc.tasks.TASKS``: each task names its own)."""
Renderer = Literal["fast", "stock", "raster"]
"""CarRacing renderers: ``fast`` (default) and ``stock`` draw identical frames; ``raster`` draws
approximate ones faster (opt-in, measured in ``results/ablation/renderer/``)."""
DEFAULT_ENV_ID: EnvId = "CarRacing-v3"
"""The env of the default task (``safe_bc.tasks.DEFAULT_TASK``)."""


@dataclass(frozen=True)
class EnvConfig:
    """Which environment to build, and how."""

    env_id: EnvId = DEFAULT_ENV_ID
    """The task's env: the id a registered task names (``make_env`` refuses any other)."""
    renderer: Renderer = "fast"
    """CarRacing only: ``"fast"`` draws pixel-identical frames faster, ``"stock"`` is
    gymnasium's own renderer, ``"raster"`` rasterises approximate frames directly at 96x96
    (faster still; frames and costs differ from stock at edges: no committed result uses it)."""
    max_episode_steps: int | None = None
    """Time limit; ``None`` keeps the env's own (1000 steps for CarRacing)."""

    def __post_init__(self) -> None:
        if not isinstance(self.env_id, str) or not self.env_id:
            raise ValueError(f"unknown env_id {self.env_id!r}")
        if self.renderer not in get_args(Renderer):
            raise ValueError(f"renderer must be one of {get_args(Renderer)}, got {self.renderer!r}")
        if self.max_episode_steps is not None and self.max_episode_steps < 1:
            raise ValueError(f"max_episode_steps must be >= 1, got {self.max_episode_steps}")
