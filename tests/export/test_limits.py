"""The limits an export carries: d_s over the scored steps, DSRL's scalar cost per step."""

from __future__ import annotations

import numpy as np
import pytest

from safe_bc.export.limits import COSTS, limits_metadata, step_costs
from safe_bc.selection import CriticalZone


def test_a_step_costs_one_only_when_scored_and_beyond_the_limit_in_some_dimension() -> None:
    costs = np.array([[2.0, 3.0], [2.0001, 0.0], [0.0, 3.5], [9.0, 9.0]])
    warmup = np.array([False, False, False, True])
    got = step_costs(costs, warmup, CriticalZone((2.0, 3.0), 0.5), "beyond")
    assert got.dtype == np.float32
    assert got.tolist() == [0.0, 1.0, 1.0, 0.0]  # at d_s: inside; warm-up: never


def test_the_default_scalar_marks_the_critical_zone_in_some_dimension() -> None:
    """``c_s >= d_s - eps`` in any dimension: the step at d_s and the ones within eps of it,
    which the beyond rule leaves at 0 on an expert set (its worst cost is d_s)."""
    zone = CriticalZone((2.0, 3.0), 0.5)
    costs = np.array([[2.0, 0.0], [1.5, 2.0], [1.4999, 2.4999], [0.0, 2.6], [9.0, 9.0]])
    warmup = np.array([False, False, False, False, True])
    assert step_costs(costs, warmup, zone).tolist() == [1.0, 1.0, 0.0, 1.0, 0.0]
    assert step_costs(costs, warmup, zone, "beyond").sum() == 0
    with pytest.raises(ValueError, match="rule must be one of"):
        step_costs(costs, warmup, zone, "violation")  # type: ignore[arg-type]


def test_costs_of_the_wrong_width_are_one_line() -> None:
    with pytest.raises(ValueError, match=r"S = 3 limits, got shape \(2, 2\)"):
        step_costs(np.zeros((2, 2)), np.zeros(2, bool), CriticalZone((1.0, 1.0, 1.0), 0.0))
    with pytest.raises(ValueError, match="2 limits for 1 safety dimensions"):
        limits_metadata(CriticalZone((1.0, 2.0), 0.5), ["left"])


def test_metadata_names_each_limit_the_width_and_the_rules() -> None:
    meta = limits_metadata(CriticalZone((1.0, 2.5), 0.5), ("left", "right"))
    assert meta["safe_bc_cost_limits"] == {"left": 1.0, "right": 2.5}
    assert meta["safe_bc_eps"] == 0.5
    zone = meta["safe_bc_critical_zone"]
    assert zone["combine"] == "any" and "c_s >= d_s - eps" in zone["critical"]
    assert "c_s > d_s" in zone["beyond"] and COSTS in zone
    assert meta["safe_bc_cost_rule"] == "critical" and "critical zone" in zone[COSTS]
    beyond = limits_metadata(CriticalZone((1.0, 2.5), 0.5), ("left", "right"), "beyond")
    assert beyond["safe_bc_cost_rule"] == "beyond"
    assert "beyond d_s" in beyond["safe_bc_critical_zone"][COSTS]
