"""The run: :func:`improve` (resumable, checkpointed) and :func:`improve_from_net`."""

from __future__ import annotations

import copy
import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd
import torch

from safe_bc.bc.checkpoint import (
    SELECTION,
    CheckpointError,
    check_checkpoint_files,
    checkpoint_unit,
    read_checkpoint_meta,
    save_checkpoint,
)
from safe_bc.bc.config import BCConfig
from safe_bc.bc.net import BCNet
from safe_bc.bc.train import torch_settings
from safe_bc.data.atomic import atomic_write
from safe_bc.data.provenance import repo_relative
from safe_bc.methods.improve.config import FORMAT, HISTORY, POLICY, STATE, ImproveConfig
from safe_bc.methods.improve.engine import Improver, _check_start_fits, _load_start, _start_meta
from safe_bc.methods.improve.envs import EnvGroupFactory, LocalEnvs
from safe_bc.methods.improve.shield import ImprovedSource
from safe_bc.selection import SelectionConfig


@dataclass(frozen=True)
class ImproveResult:
    """Outcome of :func:`improve`."""

    out: Path
    """The run directory (``state.pt``, ``history.parquet``, ``policy/``)."""
    history: pd.DataFrame = field(repr=False)
    """One row per iteration (training and validation reward / violations, multiplier)."""
    resumed_at: int
    """Iteration the call resumed from (0: a fresh run)."""
    iterations: int
    """Iterations done in total."""
    seconds: float
    """Wall time of this call."""
    kept_iteration: int
    """Iteration whose policy ``out/policy`` holds (see ``ImproveConfig.keep``)."""


def _identity(start: Path, demos: Path | None, config: ImproveConfig) -> dict[str, Any]:
    """What makes two runs the same run: config, start (path and weights), demonstrations.
    From the start's ``config.json`` alone, so a finished run is recognised without loading
    nets or demonstrations."""
    meta, demos_path = _start_meta(start, demos)
    return {
        "config": config.to_dict(),
        "start": str(start),
        "start_weights_sha256": meta["weights_sha256"],
        "demos": repo_relative(demos_path),
    }


def for_start_task(config: ImproveConfig, start: Path, demos: Path | None) -> ImproveConfig:
    """``config`` with the task's values (``TaskSpec.cost_margin``) for what it leaves at
    ``None``, the task being the start checkpoint's env's."""
    from safe_bc.tasks import task_defaults, task_of

    if config.cost_margin is not None:
        return config
    meta, _ = _start_meta(start, demos)
    return config.for_margin(task_defaults(task_of(meta["extra"]["env_id"])).cost_margin)


def improve(
    start: str | Path,
    out: str | Path,
    config: ImproveConfig | None = None,
    *,
    demos: str | Path | None = None,
    on_iteration: Callable[[dict[str, float]], None] | None = None,
    metadata: dict[str, Any] | None = None,
    envs: EnvGroupFactory = LocalEnvs,
) -> ImproveResult:
    """Improve the safety-imitation checkpoint ``start`` by constrained RL into ``out``.

    Resumes from ``out/state.pt`` when present (same start, demonstrations and config; a
    different one raises ``ValueError``); a finished run of the same start, demonstrations
    and config in ``out`` is returned as it is, without ``state.pt``. Writes ``out/policy/``
    (the improved mean net as a BC checkpoint, evaluable with ``safe-bc evaluate``; its
    ``extra["improve"]`` holds the shield's zone) and ``out/history.parquet``, the curve one
    row per iteration, mirrored as TensorBoard scalars ``improve/<column>`` in ``out``.

    Args:
        start: a ``safe-bc train`` checkpoint directory.
        out: the run directory.
        config: the run's settings.
        demos: demonstrations for the limits and the BC anchor (default: the start's).
        on_iteration: called with each iteration's history row (progress, or a test's
            interruption).
        metadata: extra fields for the outputs' provenance (e.g. the command).
        envs: where the rollout envs run (default: in this process; a
            :class:`safe_bc.distributed.envs.RayEnvs` factory spreads them over Ray actors).
            The run is bit-identical either way, so a run may resume on another group.
    """
    from safe_bc.data.curves import write_events
    from safe_bc.data.provenance import run_metadata
    from safe_bc.data.store import write_table_atomic

    start, out = Path(start), Path(out)
    t0 = time.perf_counter()
    demos = Path(demos) if demos is not None else None
    config = for_start_task(config or ImproveConfig(), start, demos)
    identity = _identity(start, demos, config)
    finished = _finished(out, identity, config.iterations)
    if finished is not None:
        history, kept = finished
        seconds = time.perf_counter() - t0
        return ImproveResult(out, history, config.iterations, config.iterations, seconds, kept)
    _check_start_fits(start, demos)
    s, data = _load_start(start, demos)
    out.mkdir(parents=True, exist_ok=True)
    state_path = out / STATE
    with torch_settings(config.num_threads):
        agent = Improver(s, data, config, envs)
        resumed_at = 0
        if state_path.exists():
            state = torch.load(state_path, map_location="cpu", weights_only=True)
            if state.get("format") != FORMAT or json.loads(state["identity"]) != identity:
                raise ValueError(
                    f"{state_path} belongs to another run (start, demos or config differ); "
                    "use another --out"
                )
            agent.load_state_dict(state)
            resumed_at = agent.iteration
        meta = run_metadata(**identity, limits=[float(x) for x in s.limits],
                            eps=agent.shield.zone.eps, combine=agent.shield.zone.combine,
                            env_id=s.env_id, mode=config.mode, **(metadata or {}))  # fmt: skip

        def save() -> None:
            state = agent.state_dict()
            state["identity"] = json.dumps(identity)
            with atomic_write(state_path) as f:
                torch.save(state, f)
            history = pd.DataFrame(agent.history)
            write_table_atomic(out / HISTORY, history, meta)
            write_events(out, history, "iteration", "improve")  # the curve in TensorBoard

        try:
            while agent.iteration < config.iterations:
                row = agent.iterate()
                if agent.iteration % config.checkpoint_every == 0:
                    save()
                if on_iteration is not None:
                    on_iteration(row)
        finally:
            agent.envs.close()
        save()
        extra = {"improve": {**meta, "start": str(start), "eps": agent.shield.zone.eps}}
        extra.update(env_id=s.env_id, demos=str(s.demos_path))
        final = copy.deepcopy(agent.actor.mean_net).eval()
        kept = agent.iteration
        if config.keep == "best_feasible" and agent.best is not None:
            kept = agent.best[0]
            final.load_state_dict(agent.best[2])
        extra["improve"]["kept_iteration"] = kept
        with checkpoint_unit(out / POLICY) as policy:  # net and selection: one unit
            save_checkpoint(policy, final, s.config, extra=extra)
            _copy_selection(start, policy)
    history = pd.DataFrame(agent.history)
    seconds = time.perf_counter() - t0
    return ImproveResult(out, history, resumed_at, agent.iteration, seconds, kept)


def improve_from_net(
    model: BCNet,
    bc_config: BCConfig,
    selection: SelectionConfig,
    demos: str | Path,
    env_id: str,
    folder: str | Path,
    config: ImproveConfig,
    *,
    metadata: dict[str, Any] | None = None,
) -> tuple[ImprovedSource, ImproveResult]:
    """Improve a trained net that is not yet a ``safe-bc train`` checkpoint (a study trial's).

    Writes it as a start checkpoint to ``folder/start`` (with its ``selection.parquet``,
    recomputed from ``selection`` on ``demos``), runs :func:`improve` into ``folder/run``
    (resuming from there; a run of other weights or settings there is discarded) and returns
    the improved agent (behind the shield when ``config.shield``) and the run's result.
    """
    from safe_bc.data.store import load_demonstrations
    from safe_bc.methods.experiment import save_selection, select_for

    folder = Path(folder)
    start, run = folder / "start", folder / "run"
    data = load_demonstrations(Path(demos))
    meta = {"env_id": env_id, "demos": repo_relative(demos)}
    with checkpoint_unit(start) as unit:
        save_checkpoint(unit, model, bc_config, extra=meta)
        save_selection(unit, data, select_for(data, selection), meta)
    try:
        result = improve(start, run, config, demos=demos, metadata=metadata)
    except ValueError as e:
        if "belongs to another run" not in str(e):
            raise
        import shutil

        shutil.rmtree(run)
        result = improve(start, run, config, demos=demos, metadata=metadata)
    return ImprovedSource.from_run(run), result


def _finished(
    out: Path, identity: dict[str, Any], iterations: int
) -> tuple[pd.DataFrame, int] | None:
    """``(history, kept iteration)`` of a finished run of this identity in ``out``, else
    ``None``. A finished run is left as it is, provenance included; its ``state.pt`` (kept out
    of git) is not needed. Its ``policy/`` must be a whole checkpoint unit (weights, config
    and selection, each matching its recorded SHA-256 where one is recorded); an incomplete
    one is written again from ``state.pt`` (or the run is redone, bit-identically)."""
    from safe_bc.data.store import read_table

    if not (out / POLICY / "config.json").is_file() or not (out / HISTORY).is_file():
        return None
    meta = read_checkpoint_meta(out / POLICY).get("extra", {}).get("improve", {})
    if {k: meta.get(k) for k in identity} != json.loads(json.dumps(identity)):
        return None
    try:
        check_checkpoint_files(out / POLICY)
    except CheckpointError:
        return None
    if not (out / POLICY / SELECTION).is_file():
        return None
    history, _ = read_table(out / HISTORY)
    if len(history) != iterations:
        return None
    return history, int(meta["kept_iteration"])


def _copy_selection(start: Path, policy_dir: Path) -> None:
    """The start's ``selection.parquet`` (thresholds, eps) next to the improved net, so that
    ``safe-bc evaluate --checkpoint OUT/policy`` measures it against the same limits."""
    from safe_bc.data.store import read_table, write_table_atomic

    table, meta = read_table(start / SELECTION)
    write_table_atomic(policy_dir / SELECTION, table, meta)
