"""``safe-bc improve``: the improve method's command from before ``safe-bc method NAME``
(:data:`safe_bc.methods.METHOD_COMMANDS`), with its own flags (``--method selfimitation``
runs the ``selfimprove`` method) and its own summary."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Annotated, Any, Literal

import tyro

from safe_bc.data.locks import output_lock
from safe_bc.methods.improve.config import ImproveConfig
from safe_bc.methods.registry import EnvGroups
from safe_bc.methods.selfimprove.config import SelfImproveConfig

Flat = tyro.conf.arg(name="")
"""A nested config whose fields are flags without its own prefix (``--iterations``, not
``--config.iterations``)."""

ImproveMethod = Literal["ppo_lagrangian", "selfimitation"]


@dataclass(frozen=True)
class ImproveJob:
    """Improve a safety-imitation checkpoint by constrained RL or filtered self-imitation
    (rerun to resume)."""

    start: Path
    """A safe-bc train checkpoint."""
    out: Path
    """Run folder (rerun to resume)."""
    method: ImproveMethod = "ppo_lagrangian"
    """ppo_lagrangian: constrained RL (--mode, --iterations, ...); selfimitation: iterated,
    filtered self-imitation inside d_s (--selfimitation.rounds, --selfimitation.pushes, ...,
    safe_bc.methods.selfimprove)."""
    demos: Path | None = None
    """Demonstrations; None: the start's."""
    config: Annotated[ImproveConfig, Flat] = field(default_factory=ImproveConfig)
    """The improvement run (method ppo_lagrangian)."""
    selfimitation: SelfImproveConfig = field(default_factory=SelfImproveConfig)
    """The self-imitation run (method selfimitation); --selfimitation.workers: its Ray
    rollout actors (0: in-process), the run is bit-identical either way."""
    rollout_workers: int = 0
    """Ray actors stepping the rollout envs (0: in-process, right for rehab; CarRacing: one
    per core); the run is bit-identical either way (method ppo_lagrangian)."""
    quiet: bool = False
    """No progress bar."""


def improve(job: ImproveJob, *, parallel: Any, envs: EnvGroups) -> tuple[str, Any]:
    """Improve a checkpoint by constrained RL or, ``method="selfimitation"``, by filtered
    self-imitation (resumable): ``(summary, the run's result)``. ``parallel``: how the
    self-imitation rounds spread their rollouts; ``envs``: the env groups of
    ``rollout_workers`` actors."""
    if job.method == "selfimitation":
        return _selfimitate(job, parallel)
    from safe_bc.methods.improve import LocalEnvs
    from safe_bc.methods.improve import improve as run_improve
    from safe_bc.progress import progress_bar

    config = job.config
    bar = progress_bar(show=not job.quiet, total=config.iterations, desc=f"improve ({config.mode})")

    def show(row: dict[str, float]) -> None:
        bar.n = int(row["iteration"])
        bar.set_postfix(reward=f"{row['train_reward']:.2f}", lam=f"{row['lambda']:.2f}",
                        viol=f"{row['train_violation_steps']:.2f}")  # fmt: skip
        bar.refresh()

    groups = envs(job.rollout_workers) if job.rollout_workers else LocalEnvs
    with output_lock(job.out), bar:
        result = run_improve(job.start, job.out, config, demos=job.demos, on_iteration=show,
                             envs=groups)  # fmt: skip
    last = result.history.dropna(subset=["val_reward"]).iloc[-1]
    return (
        f"{job.out}: {config.mode}, {result.iterations} iterations "
        f"({'resumed at ' + str(result.resumed_at) if result.resumed_at else 'fresh'}), "
        f"{int(last['env_steps'])} env steps; validation reward {last['val_reward']:.2f}, "
        f"violating sessions / patient {last['val_violation_steps']:.3f}, lambda "
        f"{last['lambda']:.2f}; policy of iteration {result.kept_iteration} in "
        f"{job.out / 'policy'}",
        result,
    )


def _selfimitate(job: ImproveJob, parallel: Any) -> tuple[str, Any]:
    from safe_bc.methods import method_of_config
    from safe_bc.methods.start import start_from_checkpoint
    from safe_bc.progress import progress_bar
    from safe_bc.tasks import task_of

    with output_lock(job.out):
        start = start_from_checkpoint(job.start, job.demos)
        rounds = job.selfimitation.for_task(task_of(start.env.env_id)).rounds
        with progress_bar(
            show=not job.quiet, total=rounds, desc="selfimitation", unit="round"
        ) as bar:

            def show(summary: dict[str, Any]) -> None:
                bar.n = int(summary["round"]) + 1  # resumed rounds count as done
                bar.set_postfix(
                    val_reward=f"{summary['validation_reward']:.2f}",
                    accepted=bool(summary["accepted"]),
                    kept=int(summary["kept_steps"]),
                )

            start = replace(start, parallel=parallel, on_round=show)
            done = method_of_config(job.selfimitation).run(job.selfimitation, start, job.out)
    result = done.result
    last = result.rounds[-1]
    return (
        f"{job.out}: selfimitation, {len(result.rounds)} rounds ({result.resumed_rounds} "
        f"resumed), {result.accepted_rounds} accepted, {result.kept_steps} kept steps; "
        f"validation reward {last['validation_reward']:.2f} (previous "
        f"{last['previous_validation_reward']:.2f}), {last['validation_beyond']} of "
        f"{job.selfimitation.validation_episodes} validation episodes beyond d_s; agent: "
        f"{result.policy}",
        result,
    )
