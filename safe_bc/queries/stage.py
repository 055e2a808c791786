"""The study's query stage (:data:`safe_bc.stages.STAGES` ``"queries"``): a trial's trained
net, retrained on critical-zone queries in the stage's folder (resumable per round)."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

from safe_bc.bc.net import BCNet
from safe_bc.queries.config import QueryConfig
from safe_bc.queries.run import QueryResult, run_queries
from safe_bc.run_config import RunConfig

if TYPE_CHECKING:
    from safe_bc.rounds import Parallel


def expert_for(demos: str | Path, env_id: str) -> Any:
    """The expert config that made ``demos`` (its ``dataset.json``), else the task's default."""
    from safe_bc.data.store import read_meta
    from safe_bc.tasks import task_defaults, task_of

    default = task_defaults(task_of(env_id)).expert
    try:
        recorded = read_meta(Path(demos)).expert or {}
    except Exception:  # a dataset without a readable record: the task's expert
        return default
    names = {f.name for f in fields(default)}
    return type(default)(**{k: v for k, v in recorded.items() if k in names})


def query_run(
    config: QueryConfig,
    agent: BCNet,
    run_config: RunConfig,
    demos: str | Path,
    env_id: str,
    folder: str | Path,
    *,
    parallel: Parallel | None = None,
    **kwargs: Any,
) -> QueryResult:
    """:func:`run_queries` with the task's env, the demonstrations' expert and action bounds,
    rolled out on ``config.workers`` workers by ``parallel`` (0: in this process)."""
    from safe_bc.data.store import load_demonstrations
    from safe_bc.tasks import dataset_action_bounds, task_defaults, task_of

    if config.workers > 0 and "rollouts" not in kwargs:
        from safe_bc.queries.rollout import query_tracks
        from safe_bc.rounds import spread

        kwargs["rollouts"] = spread(query_tracks, config.workers, parallel)
    data = load_demonstrations(Path(demos))
    env = task_defaults(task_of(env_id)).env
    return run_queries(
        agent,
        run_config,
        data,
        demos,
        env,
        expert_for(demos, env_id),
        folder,
        config,
        action_bounds=dataset_action_bounds(demos),
        **kwargs,
    )


def run_stage(
    config: QueryConfig,
    agent: Any,
    run_config: RunConfig,
    demos: str,
    env_id: str,
    folder: Path,
    *,
    parallel: Parallel | None = None,
) -> tuple[Any, dict[str, float]]:
    """The last round's agent of ``agent`` (a trained :class:`BCNet`) and its report values
    (``parallel``: how ``config.workers`` > 0 workers run the rollouts)."""
    from safe_bc.evaluation import NetSource
    from safe_bc.rounds import policy_source

    if not isinstance(agent, BCNet):
        raise TypeError(f"the query stage starts from a trained BCNet, got {type(agent)}")
    result = query_run(config, agent, run_config, demos, env_id, folder, parallel=parallel)
    source: NetSource = policy_source(result.policy)
    return source, {
        "queries_total": float(result.total_queries),
        "queries_per_episode": result.total_queries / max(result.total_episodes, 1),
        "queries_seconds": float(sum(r["seconds"] for r in result.rounds)),
    }


def query_checkpoint(
    checkpoint: str | Path,
    demos: str | Path,
    out: str | Path,
    config: QueryConfig,
    progress: bool = False,
    *,
    parallel: Parallel | None = None,
) -> QueryResult:
    """``safe-bc query``: :func:`query_run` from a ``safe-bc train`` checkpoint (its selection
    config from its ``selection.parquet`` summary, its env from its ``extra``); ``progress``:
    a bar over the rounds (on a terminal)."""
    from safe_bc.bc.checkpoint import SELECTION, load_checkpoint, read_checkpoint_meta
    from safe_bc.data.store import read_table_metadata
    from safe_bc.progress import progress_bar
    from safe_bc.selection import SelectionConfig

    model, bc = load_checkpoint(checkpoint)
    extra = read_checkpoint_meta(checkpoint).get("extra", {})
    sel = read_table_metadata(Path(checkpoint) / SELECTION)["config"]
    run_config = RunConfig(SelectionConfig(**sel), bc)
    with progress_bar(show=progress, total=config.rounds, desc="query", unit="round") as bar:

        def show(summary: dict[str, Any]) -> None:
            bar.n = int(summary["round"]) + 1  # resumed rounds count as done
            bar.set_postfix(queries=int(summary["queries"]))

        return query_run(
            config, model, run_config, demos, extra["env_id"], out, on_round=show,
            parallel=parallel,
        )  # fmt: skip
