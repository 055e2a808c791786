"""Constraints as bounds, objective with seeds: the pure pieces (no Ray)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from scipy.stats import binom

from safe_bc.metrics import clopper_pearson_upper, lower_bound_crossed
from safe_bc.study.spec import ConstraintBars, Float, StudySpec, choose_candidates, constraints
from safe_bc.study.trial import trial_values

SPACE = {"selection.alpha": Float(0.0, 1.0)}


@pytest.mark.parametrize(("k", "n"), [(0, 1), (0, 20), (3, 20), (17, 51), (1, 600), (19, 20)])
def test_clopper_pearson_upper_bound_is_exact_at_its_level(k: int, n: int) -> None:
    u = clopper_pearson_upper(k, n, 0.95)
    assert k / n < u < 1
    assert binom.cdf(k, n, u) == pytest.approx(0.05, abs=1e-9)  # exact: P(X <= k) at the bound
    assert clopper_pearson_upper(k, n, 0.99) > u > clopper_pearson_upper(k, n, 0.8)


def test_lower_bound_of_a_crossed_table_sits_below_the_mean_and_repeats() -> None:
    rng = np.random.default_rng(3)
    cells = 500 + rng.normal(0, 50, (3, 10)) + rng.normal(0, 100, 10)[None, :]
    lb = lower_bound_crossed(cells, 0.9)
    assert lb < cells.mean() and lb == lower_bound_crossed(cells, 0.9)
    assert lower_bound_crossed(cells, 0.95) < lb
    assert lower_bound_crossed(np.array([[7.0]]), 0.9) == 7.0


def _episodes(seeds: int, tracks: int, violations: int) -> pd.DataFrame:
    rows = []
    for s in range(seeds):
        for t in range(tracks):
            i = s * tracks + t
            hit = float(i < violations)
            rows.append({"train_seed": s, "env_seed": 100 + t, "reward": 600.0 + 10 * t + 5 * s,
                         "steps": 500, "safety_mean": 7.0, "violation_rate": hit / 500,
                         "any_violation": hit})  # fmt: skip
    return pd.DataFrame(rows)


def test_trial_values_with_bounds_over_seeds_and_tracks() -> None:
    spec = StudySpec("b", SPACE, train_seeds=2, reward_bound=0.9, violation_bound=0.95,
                     violation_share_limit=0.2)  # fmt: skip
    assert spec.objective == "reward_lcb" and spec.trial_seeds() == [0, 1]
    limits = ConstraintBars(
        6.0, {}, 0.0, "combined", spec.violation_bound, spec.violation_share_limit
    )
    clean = trial_values(_episodes(2, 10, 0), limits, spec)
    assert clean["train_seeds"] == 2 and clean["episodes"] == 20
    assert clean["reward_lcb"] < clean["reward_mean"]
    assert clean["violation_share_ucb"] == pytest.approx(1 - 0.05 ** (1 / 20))
    assert clean["constraint_violation"] == pytest.approx(clean["violation_share_ucb"] - 0.2)
    assert clean["constraint"] <= 0  # 0 of 20 bounds the share at 13.9% < 20%
    dirty = trial_values(_episodes(2, 10, 2), limits, spec)
    assert dirty["violation_share_ucb"] == pytest.approx(clopper_pearson_upper(2, 20))
    assert dirty["constraint"] > 0  # 2 of 20: up to 31.7%
    # the point constraint (default) is what it was: the share of steps beyond d_s
    point = ConstraintBars(6.0, {}, 0.0)
    assert constraints(dirty, point)["constraint_violation"] == pytest.approx(
        dirty["violation_rate"]
    )
    assert trial_values(_episodes(2, 10, 2), point)["constraint_violation"] == pytest.approx(
        2 / 500 / 20
    )


def test_candidates_are_ranked_on_the_objective() -> None:
    t = pd.DataFrame({"trial_id": ["a", "b"], "status": ["done"] * 2, "reward_mean": [700.0, 650.0],
                      "reward_lcb": [400.0, 600.0], "safety_mean": [7.0, 7.0],
                      "constraint": [-1.0, -1.0]})  # fmt: skip
    assert choose_candidates(t, 1)["trial_id"].tolist() == ["a"]
    assert choose_candidates(t, 1, "reward_lcb")["trial_id"].tolist() == ["b"]


@pytest.mark.parametrize(
    "bad",
    [{"violation_bound": 1.0}, {"reward_bound": 0.3}, {"train_seeds": 0},
     {"violation_share_limit": 1.5}, {"violation_share_limit": math.nan}],
)  # fmt: skip
def test_bad_bound_settings_are_rejected(bad: dict) -> None:
    with pytest.raises(ValueError):
        StudySpec("b", SPACE, **bad)


def test_defaults_keep_the_point_constraints_and_one_seed() -> None:
    spec = StudySpec("b", SPACE)
    assert spec.objective == "reward_mean" and spec.train_seeds == 1
    assert spec.violation_bound is None and spec.reward_bound is None
