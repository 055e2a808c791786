"""The limits an exported demonstration set carries, for offline safe-RL tools.

DSRL's datasets, which OSRL trains on, hold one scalar cost per step (``costs``: 1.0 where the
step is unsafe, else 0.0) and leave the safety rule to the reader. safe_bc's rule is per
safety dimension: the limit ``d_s`` is the demonstrations' worst cost in dimension ``s`` over
the scored (not warm-up) steps, a state is beyond the limit when ``c_s > d_s`` in some
dimension, and it is in the critical zone when ``c_s >= d_s - eps`` (combined over ``s`` by
``any``). An export carries both: :func:`step_costs` is the scalar DSRL reads, and
:func:`limits_metadata` the rule it was computed by.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from safe_bc.data.store import DatasetMeta, read_columns
from safe_bc.selection import CriticalZone, thresholds

COSTS = "costs"
"""Key of the scalar per-step cost in DSRL's form (its datasets' ``costs`` array)."""


def dataset_zone(root: str | Path, meta: DatasetMeta, eps: float | None = None) -> CriticalZone:
    """The critical zone of the demonstration set at ``root``: ``d_s`` its worst cost per
    dimension over the scored steps (reads only the cost and warm-up columns), ``eps`` the
    given width, else the task's default (``TaskSpec.eps``), combined by ``any``."""
    from safe_bc.tasks import task_defaults, task_of

    columns = [f"cost_{d}" for d in meta.safety_dims]
    read = read_columns(Path(root), [*columns, "warmup"])
    costs = np.stack([read[c] for c in columns], axis=1)
    limits = thresholds(costs, "max", valid=~read["warmup"].astype(bool))
    width = task_defaults(task_of(meta.env_id)).eps if eps is None else float(eps)
    return CriticalZone(limits, width)


def step_costs(costs: np.ndarray, warmup: np.ndarray, limits: Any) -> np.ndarray:
    """``(T,) float32`` in DSRL's form: 1.0 at a scored step beyond the limit in some
    dimension (``c_s > d_s``, a violation), 0.0 elsewhere; warm-up steps (not scored by
    safe_bc, and not in ``d_s``) are 0.0.

    >>> step_costs(np.array([[1.0, 3.0], [2.5, 0.0], [9.0, 9.0]]), np.array([0, 0, 1], bool),
    ...            (2.0, 3.0)).tolist()
    [0.0, 1.0, 0.0]
    """
    costs = np.asarray(costs, np.float64)
    limits = np.asarray(limits, np.float64)
    if costs.ndim != 2 or limits.shape != costs.shape[1:]:
        raise ValueError(
            f"costs must be (T, S) with S = {limits.size} limits, got shape {costs.shape}"
        )
    beyond = np.any(costs > limits, axis=1) & ~np.asarray(warmup, bool)
    return beyond.astype(np.float32)


def limits_metadata(zone: CriticalZone, dims: tuple[str, ...] | list[str]) -> dict[str, Any]:
    """Dataset-level metadata of the limits (plain JSON):

    * ``safe_bc_cost_limits``: ``{dimension: d_s}``;
    * ``safe_bc_eps``: the critical zone's width (cost units);
    * ``safe_bc_critical_zone``: the rules, as text, and ``combine``.
    """
    if len(dims) != len(zone.limits):
        raise ValueError(f"{len(zone.limits)} limits for {len(dims)} safety dimensions {dims}")
    return {
        "safe_bc_cost_limits": {d: float(x) for d, x in zip(dims, zone.limits, strict=True)},
        "safe_bc_eps": float(zone.eps),
        "safe_bc_critical_zone": {
            "combine": zone.combine,
            "critical": f"c_s >= d_s - eps, combined over the dimensions by {zone.combine!r}",
            "beyond": "c_s > d_s in some dimension (a violation)",
            "d_s": "the demonstrations' worst cost per dimension over the scored steps",
            COSTS: "1.0 at a scored step beyond d_s, else 0.0 (warm-up steps: 0.0)",
        },
    }


__all__ = ["COSTS", "dataset_zone", "limits_metadata", "step_costs"]
