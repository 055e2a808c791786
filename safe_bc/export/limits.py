"""The limits an exported demonstration set carries, for offline safe-RL tools.

DSRL's datasets, which OSRL trains on, hold one scalar cost per step (``costs``: 1.0 where the
step is unsafe, else 0.0) and leave the safety rule to the reader. safe_bc's rule is per
safety dimension: the limit ``d_s`` is the demonstrations' worst cost in dimension ``s`` over
the scored (not warm-up) steps, a state is beyond the limit when ``c_s > d_s`` in some
dimension, and it is in the critical zone when ``c_s >= d_s - eps`` (combined over ``s`` by
``any``). An export carries both: :func:`step_costs` is the scalar DSRL reads, by one of
:data:`COST_RULES`, and :func:`limits_metadata` the rule it was computed by.

The default scalar is the critical-zone indicator: ``d_s`` is the demonstrations' own worst
cost, so no demonstration step is beyond it and the ``beyond`` indicator is zero on every
step of an exported expert set (a cost-aware learner gets no signal from it); the critical
zone holds the steps nearest the limit, at least the one that set ``d_s``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal, get_args

import numpy as np

from safe_bc.data.store import DatasetMeta, read_columns
from safe_bc.selection import CriticalZone, thresholds

COSTS = "costs"
"""Key of the scalar per-step cost in DSRL's form (its datasets' ``costs`` array)."""

CostRule = Literal["critical", "beyond"]
"""Which steps the scalar cost marks: ``critical``, the critical zone (``c_s >= d_s - eps``
in some dimension); ``beyond``, a violation (``c_s > d_s`` in some dimension)."""
COST_RULES: tuple[str, ...] = get_args(CostRule)
"""The values of :data:`CostRule`."""
DEFAULT_COST_RULE: CostRule = "critical"
"""The scalar an export carries unless told otherwise (the module doc says why)."""
RULE_TEXT = {
    "critical": "1.0 at a scored step in the critical zone (c_s >= d_s - eps in some "
    "dimension), else 0.0 (warm-up steps: 0.0)",
    "beyond": "1.0 at a scored step beyond d_s (c_s > d_s in some dimension), else 0.0 "
    "(warm-up steps: 0.0)",
}
"""Each rule of the scalar cost, as the dataset metadata states it."""


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


def step_costs(
    costs: np.ndarray, warmup: np.ndarray, zone: CriticalZone, rule: CostRule = DEFAULT_COST_RULE
) -> np.ndarray:
    """``(T,) float32`` in DSRL's form: 1.0 at a scored step that ``rule`` marks in ``zone``
    (``critical``: ``c_s >= d_s - eps`` in some dimension; ``beyond``: ``c_s > d_s``), 0.0
    elsewhere; warm-up steps (not scored by safe_bc, and not in ``d_s``) are 0.0.

    >>> zone = CriticalZone((2.0, 3.0), eps=0.5)
    >>> c = np.array([[1.0, 2.6], [2.5, 0.0], [0.0, 1.0], [9.0, 9.0]])
    >>> step_costs(c, np.array([0, 0, 0, 1], bool), zone).tolist()
    [1.0, 1.0, 0.0, 0.0]
    >>> step_costs(c, np.array([0, 0, 0, 1], bool), zone, "beyond").tolist()
    [0.0, 1.0, 0.0, 0.0]
    """
    costs = np.asarray(costs, np.float64)
    if costs.ndim != 2 or costs.shape[1] != len(zone.limits):
        raise ValueError(
            f"costs must be (T, S) with S = {len(zone.limits)} limits, got shape {costs.shape}"
        )
    if rule not in COST_RULES:
        raise ValueError(f"the scalar cost's rule must be one of {COST_RULES}, got {rule!r}")
    marked = zone.critical(costs) if rule == "critical" else zone.beyond(costs)
    return (np.asarray(marked, bool) & ~np.asarray(warmup, bool)).astype(np.float32)


def limits_metadata(
    zone: CriticalZone, dims: tuple[str, ...] | list[str], rule: CostRule = DEFAULT_COST_RULE
) -> dict[str, Any]:
    """Dataset-level metadata of the limits (plain JSON):

    * ``safe_bc_cost_limits``: ``{dimension: d_s}``;
    * ``safe_bc_eps``: the critical zone's width (cost units);
    * ``safe_bc_cost_rule``: which steps the scalar ``costs`` marks (:data:`CostRule`);
    * ``safe_bc_critical_zone``: the rules, as text, and ``combine``.
    """
    if len(dims) != len(zone.limits):
        raise ValueError(f"{len(zone.limits)} limits for {len(dims)} safety dimensions {dims}")
    return {
        "safe_bc_cost_limits": {d: float(x) for d, x in zip(dims, zone.limits, strict=True)},
        "safe_bc_eps": float(zone.eps),
        "safe_bc_cost_rule": rule,
        "safe_bc_critical_zone": {
            "combine": zone.combine,
            "critical": f"c_s >= d_s - eps, combined over the dimensions by {zone.combine!r}",
            "beyond": "c_s > d_s in some dimension (a violation)",
            "d_s": "the demonstrations' worst cost per dimension over the scored steps",
            COSTS: RULE_TEXT[rule],
        },
    }


__all__ = [
    "COSTS",
    "COST_RULES",
    "DEFAULT_COST_RULE",
    "CostRule",
    "dataset_zone",
    "limits_metadata",
    "step_costs",
]
