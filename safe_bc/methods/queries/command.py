"""``safe-bc query``: the queries method's command from before ``safe-bc method NAME``
(:data:`safe_bc.methods.METHOD_COMMANDS`), with its own flags and its own summary."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Annotated, Any

import tyro

from safe_bc.methods.queries.config import QueryConfig
from safe_bc.methods.registry import EnvGroups

Flat = tyro.conf.arg(name="")
"""A nested config whose fields are flags without its own prefix (``--rounds``, not
``--config.rounds``)."""


@dataclass(frozen=True)
class QueryJob:
    """Critical-zone queries: retrain a checkpoint on expert labels of its own critical
    states, per round (rerun to resume)."""

    checkpoint: Path
    """A safe-bc train checkpoint."""
    demos: Path
    """Its demonstration dataset folder."""
    out: Path
    """Run folder (resumes a run there)."""
    config: Annotated[QueryConfig, Flat] = field(default_factory=lambda: QueryConfig(workers=2))
    """The query run (the command rolls out on 2 Ray actors unless --workers says otherwise)."""
    quiet: bool = False
    """No progress bar (it shows on a terminal only)."""


def query(job: QueryJob, *, parallel: Any, envs: EnvGroups) -> tuple[str, Any]:
    """Critical-zone queries on a checkpoint (resumable; the ``queries`` method of
    :data:`safe_bc.methods.METHODS`): ``(summary, the run's result)``. ``parallel``: how the
    rounds spread their rollouts; ``envs``: unused (the rounds roll out through
    ``parallel``)."""
    from safe_bc.methods import method_of_config
    from safe_bc.methods.start import start_from_checkpoint
    from safe_bc.progress import progress_bar

    start = start_from_checkpoint(job.checkpoint, job.demos)
    rounds = job.config.rounds
    with progress_bar(show=not job.quiet, total=rounds, desc="query", unit="round") as bar:

        def show(summary: dict[str, Any]) -> None:
            bar.n = int(summary["round"]) + 1  # resumed rounds count as done
            bar.set_postfix(queries=int(summary["queries"]))

        start = replace(start, parallel=parallel, on_round=show)
        result = method_of_config(job.config).run(job.config, start, job.out).result
    return (
        f"{result.total_queries} queries in {result.total_episodes} episodes; "
        f"agent: {result.policy}",
        result,
    )
