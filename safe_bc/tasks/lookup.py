"""Task facts read from the registry: action bounds of an env or dataset, and whether a net
fits a task (no per-task branches: every value comes from a :class:`TaskSpec`)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from safe_bc.tasks.env_config import RENDERER_ALIASES, EnvConfig
from safe_bc.tasks.registry import Bounds, task_defaults, task_of

if TYPE_CHECKING:
    from safe_bc.run_config import RunConfig


def check_net_fits_task(
    obs_shape: tuple[int, ...], action_dim: int, env_id: str, where: Any
) -> None:
    """A net trained for one task must not be run on another: its observation rank (frames
    or vectors) and action count must be the task's. Checked before any env is started.

    Raises:
        ValueError: one line naming ``where`` (the checkpoint) and both shapes.
    """
    task = task_defaults(task_of(env_id))
    rank, dims = (1 if task.encoding == "vector" else 3), len(task.action_bounds[0])
    if len(obs_shape) != rank or action_dim != dims:
        kind = "vectors" if rank == 1 else "frames"
        raise ValueError(
            f"{where}: its net takes observations of shape {tuple(obs_shape)} and gives "
            f"{action_dim} action(s), but it names {env_id} ({kind}, {dims} action(s)); the "
            "checkpoint's env_id is not the task it was trained on"
        )


def with_task_eps(run: RunConfig, env_id: str) -> RunConfig:
    """``run`` with the critical-zone width of the task whose env is ``env_id``
    (``TaskSpec.eps``) where its ``selection.eps`` is unset (``None``); a set width is kept.
    The one place an unset width becomes the task's: studies, ``safe-bc train`` and
    comparisons call it.

    >>> from safe_bc.run_config import RunConfig
    >>> from safe_bc.selection import SelectionConfig
    >>> with_task_eps(RunConfig(), "safe_bc/RehabPathway-v0").selection.eps
    0.05
    >>> with_task_eps(RunConfig(SelectionConfig(eps=0.3)), "CarRacing-v3").selection.eps
    0.3
    """
    if run.selection.eps is not None:
        return run
    eps = task_defaults(task_of(env_id)).eps
    return replace(run, selection=run.selection.with_eps(eps))


def dataset_action_bounds(root: str | Path) -> Bounds:
    """The action bounds of the dataset at ``root``: from its ``dataset.json``, or, for a
    dataset collected before the bounds were recorded there, from its task's entry."""
    from safe_bc.data.store import read_meta

    meta = read_meta(Path(root))
    if meta.action_bounds is not None:
        return meta.action_bounds
    return task_defaults(task_of(meta.env_id)).action_bounds


def action_bounds(env_config: EnvConfig) -> Bounds:
    """``(low, high)`` of the env's Box action space, read from a built env."""
    from safe_bc.tasks.factory import make_env

    env = make_env(env_config)
    try:
        space = env.action_space
        return tuple(float(x) for x in space.low), tuple(float(x) for x in space.high)
    finally:
        env.close()


def frames_renderer(env: EnvConfig) -> str | None:
    """The renderer that draws ``env``'s frames, as a dataset records it: ``None`` for a task
    without renderers."""
    return env.renderer if task_defaults(task_of(env.env_id)).has_renderer else None


def check_frames_renderer(recorded: str | None, env: EnvConfig, where: Any) -> str | None:
    """Demonstrations drawn by one renderer must not train an agent evaluated on another.

    Returns a one-line warning when ``recorded`` is ``None`` on a task with renderers (a set
    collected before the renderer was recorded: it cannot be checked), else ``None``.

    Raises:
        ValueError: one line naming ``where`` and both renderers.

    >>> check_frames_renderer("raster", EnvConfig(renderer="exact"), "demos")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    ValueError: demos holds frames drawn by the 'raster' renderer, but the env draws ...
    """
    wanted = frames_renderer(env)
    if wanted is None:
        return None
    if recorded is None:
        return (
            f"{where} does not record its renderer (collected before 2026-11-26, when the "
            f"default was 'exact'); the env draws with {wanted!r}: recollect to be sure"
        )
    recorded = RENDERER_ALIASES.get(recorded, recorded)
    if recorded != wanted:
        raise ValueError(
            f"{where} holds frames drawn by the {recorded!r} renderer, but the env draws with "
            f"{wanted!r}: collect demonstrations drawn by {wanted!r} (safe-bc collect "
            f"--renderer {wanted}) or evaluate with renderer {recorded!r}"
        )
    return None
