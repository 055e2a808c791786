"""A method's start from a ``safe-bc train`` checkpoint (``safe-bc method``)."""

from __future__ import annotations

from pathlib import Path

from safe_bc.methods.registry import Start


def start_from_checkpoint(checkpoint: str | Path, demos: str | Path | None = None) -> Start:
    """The :class:`Start` of a ``safe-bc train`` checkpoint: its net, its selection config
    (from its ``selection.parquet`` summary) and BC settings, its task's env and ``demos``
    (``None``: the demonstrations it was trained on)."""
    from safe_bc.bc.checkpoint import SELECTION, load_checkpoint, read_checkpoint_meta
    from safe_bc.data.store import read_table_metadata
    from safe_bc.run_config import RunConfig
    from safe_bc.selection import SelectionConfig
    from safe_bc.tasks import task_defaults, task_of

    model, bc = load_checkpoint(checkpoint)
    extra = read_checkpoint_meta(checkpoint).get("extra", {})
    sel = read_table_metadata(Path(checkpoint) / SELECTION)["config"]
    env = task_defaults(task_of(extra["env_id"])).env
    data = demos if demos is not None else extra["demos"]
    return Start(model, RunConfig(SelectionConfig(**sel), bc), data, env, Path(checkpoint))
