"""The study's self-imitation stage (:data:`safe_bc.stages.STAGES` ``"selfimprove"``): a
trial's trained net, improved by filtered self-imitation in the stage's folder (resumable per
round), and ``safe-bc improve --method selfimitation`` from a checkpoint."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from safe_bc.bc.net import BCNet
from safe_bc.run_config import RunConfig
from safe_bc.selfimprove.config import SelfImproveConfig
from safe_bc.selfimprove.run import SelfImproveResult, run_selfimprove

if TYPE_CHECKING:
    from safe_bc.rounds import Parallel


def selfimprove_run(
    config: SelfImproveConfig,
    agent: BCNet,
    run_config: RunConfig,
    demos: str | Path,
    env_id: str,
    folder: str | Path,
    *,
    parallel: Parallel | None = None,
    **kwargs: Any,
) -> SelfImproveResult:
    """:func:`run_selfimprove` with the task's env, the task's values for the fields
    ``config`` leaves at ``None`` (:meth:`SelfImproveConfig.for_task`) and the demonstrations'
    action bounds, rolled out on ``config.workers`` workers by ``parallel`` (0: in this
    process)."""
    from safe_bc.data.store import load_demonstrations
    from safe_bc.tasks import dataset_action_bounds, task_defaults, task_of

    if config.workers > 0 and "rollouts" not in kwargs:
        from safe_bc.rounds import spread
        from safe_bc.selfimprove.rollout import local_rollouts

        kwargs["rollouts"] = spread(local_rollouts, config.workers, parallel)
    task = task_of(env_id)
    return run_selfimprove(
        agent,
        run_config,
        load_demonstrations(Path(demos)),
        demos,
        task_defaults(task).env,
        folder,
        config.for_task(task),
        action_bounds=dataset_action_bounds(demos),
        **kwargs,
    )


def run_stage(
    config: SelfImproveConfig,
    agent: Any,
    run_config: RunConfig,
    demos: str,
    env_id: str,
    folder: Path,
    *,
    parallel: Parallel | None = None,
) -> tuple[Any, dict[str, float]]:
    """The final agent of ``agent`` (a trained :class:`BCNet`) and its report values
    (``parallel``: how ``config.workers`` > 0 workers run the rollouts)."""
    from safe_bc.rounds import policy_source

    if not isinstance(agent, BCNet):
        raise TypeError(f"the self-imitation stage starts from a trained BCNet, got {type(agent)}")
    result = selfimprove_run(config, agent, run_config, demos, env_id, folder, parallel=parallel)
    return policy_source(result.policy), {
        "selfimprove_accepted_rounds": float(result.accepted_rounds),
        "selfimprove_kept_steps": float(result.kept_steps),
        "selfimprove_seconds": float(sum(r["seconds"] for r in result.rounds)),
    }


def selfimprove_checkpoint(
    checkpoint: str | Path,
    demos: str | Path | None,
    out: str | Path,
    config: SelfImproveConfig,
    progress: bool = False,
    *,
    parallel: Parallel | None = None,
) -> SelfImproveResult:
    """``safe-bc improve --method selfimitation``: :func:`selfimprove_run` from a
    ``safe-bc train`` checkpoint (its selection config from its ``selection.parquet``
    summary, its env and, without ``demos``, its demonstrations from its ``extra``);
    ``progress``: a bar over the rounds (on a terminal) with each round's validation."""
    from safe_bc.bc.checkpoint import SELECTION, load_checkpoint, read_checkpoint_meta
    from safe_bc.data.store import read_table_metadata
    from safe_bc.progress import progress_bar
    from safe_bc.selection import SelectionConfig
    from safe_bc.tasks import task_of

    model, bc = load_checkpoint(checkpoint)
    extra = read_checkpoint_meta(checkpoint).get("extra", {})
    sel = read_table_metadata(Path(checkpoint) / SELECTION)["config"]
    run_config = RunConfig(SelectionConfig(**sel), bc)
    data = demos if demos is not None else extra["demos"]
    rounds = config.for_task(task_of(extra["env_id"])).rounds
    with progress_bar(show=progress, total=rounds, desc="selfimitation", unit="round") as bar:

        def show(summary: dict[str, Any]) -> None:
            bar.n = int(summary["round"]) + 1  # resumed rounds count as done
            bar.set_postfix(
                val_reward=f"{summary['validation_reward']:.2f}",
                accepted=bool(summary["accepted"]),
                kept=int(summary["kept_steps"]),
            )

        return selfimprove_run(
            config, model, run_config, data, extra["env_id"], out, on_round=show,
            parallel=parallel,
        )  # fmt: skip
