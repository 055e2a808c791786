"""The ``improve`` method's runner (:data:`safe_bc.methods.METHODS` ``"improve"``): a start
agent improved by constrained RL in its own folder (resumable)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from safe_bc.methods.improve.config import ImproveConfig
from safe_bc.methods.registry import Improved, Start


def identity(config: ImproveConfig, task: str) -> dict[str, Any]:
    """What makes a run of ``config`` on ``task``: its fields, with the task's margin where it
    leaves ``cost_margin`` at ``None`` (what the run executes and records)."""
    from safe_bc.tasks import task_defaults

    return config.for_margin(task_defaults(task).cost_margin).to_dict()


def run(
    config: ImproveConfig, start: Start, folder: Path, *, metadata: dict[str, Any] | None = None
) -> Improved:
    """:func:`safe_bc.methods.improve.improve` from ``start``: from its checkpoint into ``folder``
    itself when it is one (a comparison's agent, ``--start``), else (a study trial's net) by
    :func:`safe_bc.methods.improve.run.improve_from_net` (``folder/start``, ``folder/run``). The
    policy is the improved agent behind its shield when ``config.shield``; the net, without."""
    from safe_bc.data.store import read_table
    from safe_bc.methods.improve import HISTORY, ImprovedSource, improve, improve_from_net

    if start.checkpoint is None:
        rc = start.run_config
        source, result = improve_from_net(
            start.agent, rc.bc, rc.selection, start.demos, start.env.env_id, folder, config,
            metadata=metadata,
        )  # fmt: skip
        meta = None
    else:
        result = improve(start.checkpoint, folder, config, demos=start.demos, metadata=metadata)
        source = ImprovedSource.from_run(folder)
        meta = read_table(folder / HISTORY)[1]
    return Improved(
        policy=source,
        net=source.improved,
        report={
            "improve_seconds": float(result.history["seconds"].sum()),
            "improve_kept_iteration": float(result.kept_iteration),
        },
        history=result.history,
        meta=meta,
        fresh=result.resumed_at < result.iterations,
        result=result,
    )
