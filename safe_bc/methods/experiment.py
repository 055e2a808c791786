"""One safety-imitation run: select T_eps, train BC on alpha-mixed batches (no Ray).

This is what a row of Table 1 and every study trial does before evaluation.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from safe_bc.bc import TrainResult, sampler_for, train_bc
from safe_bc.bc.train import LogFn
from safe_bc.data.demos import Demonstrations
from safe_bc.run_config import RunConfig as RunConfig
from safe_bc.selection import Selection, SelectionConfig, select


def select_for(demos: Demonstrations, config: SelectionConfig) -> Selection:
    """T_eps of ``demos`` under ``config`` (warm-up steps excluded; BC-Safe's segments cut at
    episode boundaries)."""
    return select(demos.costs, config, demos.scored, demos.safety_dims, demos.episode_ids)


def train_run(
    demos: Demonstrations,
    config: RunConfig,
    *,
    selection: Selection | None = None,
    progress: bool = False,
    log_fn: LogFn | None = None,
    action_bounds: tuple[np.ndarray, np.ndarray] | None = None,
    validation: Demonstrations | None = None,
) -> tuple[TrainResult, Selection]:
    """Select the critical subset and train one BC agent on its mix (or baseline rule);
    ``validation``: held-out demonstrations whose loss the curve records
    (:func:`safe_bc.data.demos.hold_out_episodes`), never trained on.

    Raises:
        SelectionError: the mix cannot be built (e.g. alpha > 0 with an empty T_eps, or no
            BC-Safe segment outside T_eps).
    """
    selection = selection or select_for(demos, config.selection)
    sampler = sampler_for(selection, config.bc.train)  # validates the mix before training
    result = train_bc(
        demos,
        sampler,
        config.bc.network,
        config.bc.preprocess,
        config.bc.train,
        progress=progress,
        log_fn=log_fn,
        action_bounds=action_bounds,
        validation=validation,
    )
    return result, selection


def save_curve(
    directory: Path, result: TrainResult, meta: dict[str, Any], prefix: str = "bc"
) -> Path:
    """Write ``result``'s learning curve as ``directory/curve.parquet`` (with ``meta``) and as
    TensorBoard scalars ``prefix/train_loss``, ``prefix/val_loss``, ... at each logged batch."""
    from safe_bc.bc.checkpoint import CURVE
    from safe_bc.data.curves import write_curve

    return write_curve(Path(directory) / CURVE, result.curve(), "batch", prefix, meta)


def selection_table(demos: Demonstrations, selection: Selection) -> pd.DataFrame:
    """Which demonstrations were critical: one row per step, per-dimension flags and costs
    (plus ``weight`` and, for BC-Safe, ``segment`` for the baseline modes)."""
    df = pd.DataFrame(
        {
            "episode_id": demos.episode_ids,
            "step": demos.steps,
            "seed": demos.seeds,
            "scored": selection.valid,
            "critical": selection.mask,
        }
    )
    for j, d in enumerate(demos.safety_dims):
        df[f"cost_{d}"] = demos.costs[:, j]
        df[f"critical_{d}"] = selection.per_dim[:, j]
    if selection.weights is not None:  # the baselines: each row's sampling weight
        df["weight"] = selection.weights
    if selection.segments is not None:
        df["segment"] = selection.segments
    return df


def save_selection(
    directory: Path, demos: Demonstrations, selection: Selection, meta: dict[str, Any]
) -> Path:
    """Write ``selection.parquet`` (the mask per step; thresholds in its metadata)."""
    from safe_bc.data.store import write_table_atomic

    path = Path(directory) / "selection.parquet"
    write_table_atomic(path, selection_table(demos, selection), {**meta, **selection.to_dict()})
    return path
