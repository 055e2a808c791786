"""The ``queries`` method's runner (:data:`safe_bc.methods.METHODS` ``"queries"``): a start
agent retrained on critical-zone queries in its folder (resumable per round)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import pandas as pd

from safe_bc.bc.net import BCNet
from safe_bc.methods.queries.config import QueryConfig
from safe_bc.methods.queries.run import QueryResult, run_queries
from safe_bc.methods.registry import Improved, Start
from safe_bc.rollout.collect import expert_for
from safe_bc.run_config import RunConfig
from safe_bc.tasks.env_config import EnvConfig

if TYPE_CHECKING:
    from safe_bc.methods.rounds import Parallel


def query_run(
    config: QueryConfig,
    agent: BCNet,
    run_config: RunConfig,
    demos: str | Path,
    env: str | EnvConfig,
    folder: str | Path,
    *,
    parallel: Parallel | None = None,
    **kwargs: Any,
) -> QueryResult:
    """:func:`run_queries` in ``env`` (an env id: the task's env), with the demonstrations'
    expert and action bounds, rolled out on ``config.workers`` workers by ``parallel`` (0: in
    this process)."""
    from safe_bc.data.store import load_demonstrations
    from safe_bc.tasks import dataset_action_bounds, task_defaults, task_of

    if config.workers > 0 and "rollouts" not in kwargs:
        from safe_bc.methods.queries.rollout import query_tracks
        from safe_bc.methods.rounds import spread

        kwargs["rollouts"] = spread(query_tracks, config.workers, parallel)
    data = load_demonstrations(Path(demos))
    if isinstance(env, str):
        env = task_defaults(task_of(env)).env
    return run_queries(
        agent,
        run_config,
        data,
        demos,
        env,
        expert_for(demos, env.env_id),
        folder,
        config,
        action_bounds=dataset_action_bounds(demos),
        **kwargs,
    )


def run(
    config: QueryConfig, start: Start, folder: Path, *, metadata: dict[str, Any] | None = None
) -> Improved:
    """The ``queries`` method's runner (:data:`safe_bc.methods.METHODS`): the last round's
    agent of ``start`` and its report values (``metadata`` is not stored: the rounds carry
    their own); its rollouts spread by ``start.parallel``, each round shown to
    ``start.on_round``."""
    from safe_bc.methods.rounds import policy_source

    if config.budget_of:
        raise ValueError(
            f"budget_of={config.budget_of!r} names a comparison row: resolve it first "
            "(QueryConfig.with_budget; the comparison runner does)"
        )
    result = query_run(
        config, start.agent, start.run_config, start.demos, start.env, folder,
        parallel=start.parallel, on_round=start.on_round,
    )  # fmt: skip
    source = policy_source(result.policy)
    seconds = [float(r["seconds"]) for r in result.rounds]
    return Improved(
        policy=source,
        net=source,
        report={
            "queries_total": float(result.total_queries),
            "queries_per_episode": result.total_queries / max(result.total_episodes, 1),
            "queries_seconds": float(sum(seconds)),
        },
        history=pd.DataFrame(
            {
                "iteration": range(1, len(seconds) + 1),
                "seconds": seconds,
                "queries": [int(r["queries"]) for r in result.rounds],
                "episodes": [int(r["episodes"]) for r in result.rounds],
            }
        ),
        fresh=result.resumed_rounds < len(result.rounds),
        result=result,
    )
