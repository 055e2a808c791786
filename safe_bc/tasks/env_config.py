"""Which environment to build, and how (a frozen record; nothing is built here)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

EnvId = str
"""The env id a task registers (``safe_bc.tasks.TASKS``: each task names its own)."""
Renderer = Literal["raster", "exact", "stock"]
"""CarRacing renderers: ``raster`` (default) rasterises approximate frames straight at 96x96;
``exact`` (called ``fast`` before 2026-11-26) and ``stock`` draw frames pixel-identical to
gymnasium's. The default was chosen by the renderer ablation (``results/ablation/renderer/``:
no reliable difference in outcomes between exact and raster pipelines) and the speed
measurement (``make bench``, the ``env`` case)."""
DEFAULT_RENDERER: Renderer = "raster"
"""The renderer an ``EnvConfig`` uses unless told otherwise (see :data:`Renderer`)."""
RENDERER_ALIASES: dict[str, Renderer] = {"fast": "exact"}
"""Former renderer names, still read (configs and tables written before the rename)."""


def canonical_renderer(name: str) -> Renderer:
    """``name`` with a former name replaced by today's (``"fast"`` -> ``"exact"``); one clear
    error for anything else.

    >>> canonical_renderer("fast"), canonical_renderer("raster")
    ('exact', 'raster')
    """
    name = RENDERER_ALIASES.get(name, name)  # type: ignore[arg-type]
    if name not in get_args(Renderer):
        raise ValueError(f"renderer must be one of {get_args(Renderer)}, got {name!r}")
    return name  # type: ignore[return-value]


DEFAULT_ENV_ID: EnvId = "CarRacing-v3"
"""The env of the default task (``safe_bc.tasks.DEFAULT_TASK``)."""


@dataclass(frozen=True)
class EnvConfig:
    """Which environment to build, and how."""

    env_id: EnvId = DEFAULT_ENV_ID
    """The task's env: the id a registered task names (``make_env`` refuses any other)."""
    renderer: Renderer = DEFAULT_RENDERER
    """CarRacing only: ``"raster"`` (default) rasterises approximate frames directly at 96x96
    (fastest; frames and costs differ from stock's at edges, measured in
    ``results/ablation/renderer/``), ``"exact"`` draws stock's frames pixel for pixel, faster
    than ``"stock"``, gymnasium's own renderer. ``"fast"``, the former name of ``"exact"``,
    is read as ``"exact"``."""
    max_episode_steps: int | None = None
    """Time limit; ``None`` keeps the env's own (1000 steps for CarRacing)."""

    def __post_init__(self) -> None:
        if not isinstance(self.env_id, str) or not self.env_id:
            raise ValueError(f"unknown env_id {self.env_id!r}")
        object.__setattr__(self, "renderer", canonical_renderer(self.renderer))
        if self.max_episode_steps is not None and self.max_episode_steps < 1:
            raise ValueError(f"max_episode_steps must be >= 1, got {self.max_episode_steps}")
