"""The study's improvement stage (:data:`safe_bc.stages.STAGES` ``"improve"``): a trial's
trained net, improved by constrained RL in the stage's folder (resumable)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from safe_bc.bc.net import BCNet
from safe_bc.improve.config import ImproveConfig
from safe_bc.improve.run import improve_from_net
from safe_bc.run_config import RunConfig


def run_stage(
    config: ImproveConfig,
    agent: Any,
    run_config: RunConfig,
    demos: str,
    env_id: str,
    folder: Path,
    *,
    parallel: Any = None,
) -> tuple[Any, dict[str, float]]:
    """The improved agent of ``agent`` (a trained :class:`BCNet`) and its report values
    (``parallel`` is unused: the stage's rollout envs run in this process)."""
    if not isinstance(agent, BCNet):
        raise TypeError(f"the improvement stage starts from a trained BCNet, got {type(agent)}")
    source, result = improve_from_net(
        agent, run_config.bc, run_config.selection, demos, env_id, folder, config
    )
    return source, {
        "improve_seconds": float(result.history["seconds"].sum()),
        "improve_kept_iteration": float(result.kept_iteration),
    }
