"""Metrics and bootstrap confidence intervals."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from safe_bc.metrics import bootstrap_ci, critical_zone, summarize


def test_ci_covers_the_true_mean_most_of_the_time() -> None:
    rng = np.random.default_rng(0)
    hits = 0
    for _ in range(100):
        x = rng.normal(3.0, 1.0, 30)
        _, lo, hi = bootstrap_ci(x, rng=rng, n_boot=200)
        hits += lo <= 3.0 <= hi
    assert 0.85 <= hits / 100 <= 0.995


def test_two_level_ci_is_wider_when_seeds_disagree() -> None:
    rng = np.random.default_rng(1)
    groups = np.repeat([0, 1, 2], 10)
    x = np.repeat([0.0, 5.0, 10.0], 10) + rng.normal(0, 0.1, 30)
    _, lo1, hi1 = bootstrap_ci(x, rng=np.random.default_rng(0))
    _, lo2, hi2 = bootstrap_ci(x, groups, rng=np.random.default_rng(0))
    assert hi2 - lo2 > 1.5 * (hi1 - lo1)


def test_bad_confidence() -> None:
    with pytest.raises(ValueError, match="confidence"):
        bootstrap_ci(np.ones(3), confidence=1.5, rng=np.random.default_rng(0))


def test_critical_zone() -> None:
    costs = np.array([[10.0, 0.0], [4.0, 9.5], [1.0, 1.0]])
    assert critical_zone(costs, np.array([10.0, 10.0]), 1.0).tolist() == [True, True, False]


def test_summarize_columns() -> None:
    df = pd.DataFrame(
        {"alpha": [0, 0, 0.5, 0.5], "train_seed": [0, 1, 0, 1], "reward": [1.0, 2, 3, 4]}
    )
    out = summarize(df, ["alpha"], ["reward"])
    assert out.columns.tolist() == [
        "alpha",
        "n_episodes",
        "n_train_seeds",
        "reward",
        "reward_lo",
        "reward_hi",
    ]
    assert out["reward"].tolist() == [1.5, 3.5]
