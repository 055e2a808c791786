"""Task facts read from the registry: action bounds of an env or dataset, and whether a net
fits a task (no per-task branches: every value comes from a :class:`TaskSpec`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from safe_bc.envs.config import EnvConfig
from safe_bc.tasks.registry import Bounds, task_defaults, task_of


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
    from safe_bc.envs.factory import make_env

    env = make_env(env_config)
    try:
        space = env.action_space
        return tuple(float(x) for x in space.low), tuple(float(x) for x in space.high)
    finally:
        env.close()
