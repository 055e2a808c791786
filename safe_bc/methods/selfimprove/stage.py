"""The ``selfimprove`` method's runner (:data:`safe_bc.methods.METHODS` ``"selfimprove"``): a
start agent improved by filtered self-imitation in its folder (resumable per round)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import pandas as pd

from safe_bc.bc.net import BCNet
from safe_bc.methods.registry import Improved, Start
from safe_bc.methods.selfimprove.config import SelfImproveConfig
from safe_bc.methods.selfimprove.run import SelfImproveResult, run_selfimprove
from safe_bc.run_config import RunConfig
from safe_bc.tasks.env_config import EnvConfig

if TYPE_CHECKING:
    from safe_bc.methods.rounds import Parallel


def selfimprove_run(
    config: SelfImproveConfig,
    agent: BCNet,
    run_config: RunConfig,
    demos: str | Path,
    env: str | EnvConfig,
    folder: str | Path,
    *,
    parallel: Parallel | None = None,
    data: Any = None,
    **kwargs: Any,
) -> SelfImproveResult:
    """:func:`run_selfimprove` in ``env`` (an env id: the task's env), with the task's values
    for the fields ``config`` leaves at ``None`` (:meth:`SelfImproveConfig.for_task`) and the
    demonstrations' action bounds (``data``: ``demos`` loaded already), rolled out on
    ``config.workers`` workers by ``parallel`` (0: in this process)."""
    from safe_bc.data.store import load_demonstrations
    from safe_bc.tasks import dataset_action_bounds, task_defaults, task_of

    if config.workers > 0 and "rollouts" not in kwargs:
        from safe_bc.methods.rounds import spread
        from safe_bc.methods.selfimprove.rollout import local_rollouts

        kwargs["rollouts"] = spread(local_rollouts, config.workers, parallel)
    if isinstance(env, str):
        env = task_defaults(task_of(env)).env
    task = task_of(env.env_id)
    return run_selfimprove(
        agent,
        run_config,
        load_demonstrations(Path(demos)) if data is None else data,
        demos,
        env,
        folder,
        config.for_task(task),
        action_bounds=dataset_action_bounds(demos),
        **kwargs,
    )


def run(
    config: SelfImproveConfig,
    start: Start,
    folder: Path,
    *,
    metadata: dict[str, Any] | None = None,
) -> Improved:
    """The ``selfimprove`` method's runner (:data:`safe_bc.methods.METHODS`): the final agent
    of ``start`` in ``start.env`` and its report values (``metadata`` is not stored: the
    comparison runner records the machine beside the run)."""
    from safe_bc.methods.rounds import policy_source

    kwargs: dict[str, Any] = {} if start.data is None else {"data": start.data}
    if start.shared is not None:
        kwargs["shared"] = start.shared
    result = selfimprove_run(
        config, start.agent, start.run_config, start.demos, start.env, folder,
        parallel=start.parallel, on_round=start.on_round, **kwargs,
    )  # fmt: skip
    source = policy_source(result.policy)
    return Improved(
        policy=source,
        net=source,
        report={
            "selfimprove_accepted_rounds": float(result.accepted_rounds),
            "selfimprove_kept_steps": float(result.kept_steps),
            "selfimprove_seconds": float(sum(r["seconds"] for r in result.rounds)),
        },
        history=pd.DataFrame(result.history()),
        fresh=result.resumed_rounds < len(result.rounds),
        result=result,
    )


def identity(config: SelfImproveConfig, task: str) -> dict[str, Any]:
    """What makes a run of ``config`` on ``task``: its config (``workers`` aside) with the
    task's values filled in (a task's defaults may change)."""
    resolved = config.for_task(task)
    assert resolved.pushes is not None
    return {**resolved.identity(), "pushes": list(resolved.pushes)}
