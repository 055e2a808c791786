"""Metrics and bootstrap confidence intervals."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from safe_bc.metrics import (
    bootstrap_ci,
    critical_zone,
    crossed_bootstrap_ci,
    paired_crossed,
    summarize,
    summarize_crossed,
)


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


# --- crossed bootstrap: shared training seeds x shared tracks ----------------------------


def _crossed_episodes(values: dict[str, np.ndarray]) -> pd.DataFrame:
    """Long table from ``{method: (seeds, tracks) reward}``; tracks are env seeds 100.."""
    rows = []
    for method, cells in values.items():
        for s in range(cells.shape[0]):
            for t in range(cells.shape[1]):
                rows.append(
                    {"method": method, "train_seed": s, "env_seed": 100 + t, "reward": cells[s, t]}
                )
    return pd.DataFrame(rows)


def test_pure_track_effect_gives_a_zero_width_paired_interval() -> None:
    rng = np.random.default_rng(0)
    track = rng.normal(0, 100, 20)  # hard and easy tracks, the same for every method and seed
    seeds = rng.normal(0, 5, (8, 1))
    cells = {"bc": seeds + track, "a": seeds + track + 7.0, "b": seeds + track - 2.0}
    episodes = _crossed_episodes(cells)
    table = summarize_crossed(episodes, ["method"], ["reward"])
    paired = paired_crossed(episodes, "bc", ["reward"]).set_index("method")
    assert paired.loc["a", "d_reward"] == pytest.approx(7.0)
    assert paired.loc["a", "d_reward_lo"] == pytest.approx(7.0)
    assert paired.loc["a", "d_reward_hi"] == pytest.approx(7.0)
    assert paired.loc["b", "d_reward_hi"] - paired.loc["b", "d_reward_lo"] == pytest.approx(0.0)
    assert paired.loc["a", "seeds_better"] == 8 and paired.loc["b", "seeds_better"] == 0
    assert (paired["n_seeds_paired"] == 8).all() and (paired["n_pairs"] == 160).all()
    # the method means themselves carry the track spread
    width = table["reward_hi"] - table["reward_lo"]
    assert (width > 20).all()
    assert table[["n_train_seeds", "n_tracks", "n_episodes"]].values.tolist() == [[8, 20, 160]] * 3


def test_crossed_mean_inside_interval_and_deterministic() -> None:
    rng = np.random.default_rng(1)
    cells = rng.normal(5, 1, (4, 6)) + rng.normal(0, 2, (1, 6))
    cells[2, 3] = np.nan  # a missing evaluation is skipped
    a = crossed_bootstrap_ci(cells, rng=np.random.default_rng(7))
    b = crossed_bootstrap_ci(cells, rng=np.random.default_rng(7))
    assert a == b
    mean, lo, hi = a
    assert mean == pytest.approx(np.nanmean(cells)) and lo < mean < hi
    assert crossed_bootstrap_ci(np.array([[3.0]]), rng=rng) == (3.0, 3.0, 3.0)
    assert np.isnan(crossed_bootstrap_ci(np.full((2, 2), np.nan), rng=rng)[0])
    with pytest.raises(ValueError, match="seeds, tracks"):
        crossed_bootstrap_ci(np.ones(3), rng=rng)
    with pytest.raises(ValueError, match="confidence"):
        crossed_bootstrap_ci(np.ones((2, 2)), confidence=1.0, rng=rng)


def test_one_seed_is_a_bootstrap_over_tracks() -> None:
    x = np.arange(10.0)
    crossed = crossed_bootstrap_ci(x[None, :], rng=np.random.default_rng(0))
    plain = bootstrap_ci(x, rng=np.random.default_rng(1))
    assert crossed[0] == plain[0]
    assert abs((crossed[2] - crossed[1]) - (plain[2] - plain[1])) < 1.0


def test_crossed_covers_shared_track_effects_better_than_nested() -> None:
    # 4 seeds x 10 shared tracks; the track effect dominates; the true mean is 0
    rng = np.random.default_rng(0)
    s, t, n = 4, 10, 100
    hits_crossed = hits_nested = 0
    for _ in range(n):
        y = rng.normal(0, 0.3, (s, 1)) + rng.normal(0, 1, (1, t)) + rng.normal(0, 0.3, (s, t))
        _, lo, hi = crossed_bootstrap_ci(y, n_boot=200, rng=rng)
        hits_crossed += lo <= 0 <= hi
        _, lo, hi = bootstrap_ci(y.ravel(), np.repeat(np.arange(s), t), n_boot=200, rng=rng)
        hits_nested += lo <= 0 <= hi
    assert hits_crossed / n >= 0.8
    assert hits_crossed - hits_nested >= 8


def test_seeds_better_counts_seed_means() -> None:
    base = np.zeros((3, 4))
    other = np.array([[1.0, 1, 1, 1], [-5, 1, 1, 1], [0.5, -0.1, 0, 0]])  # seed means 1, -0.5, .1
    episodes = _crossed_episodes({"bc": base, "x": other})
    out = paired_crossed(episodes, "bc", ["reward"]).iloc[0]
    assert (out["seeds_better"], out["n_seeds_paired"]) == (2, 3)
    # an expert evaluated once, under a seed the agents lack, has no pairs
    expert = _crossed_episodes({"expert": np.ones((1, 4))}).assign(train_seed=99)
    again = paired_crossed(pd.concat([episodes, expert]), "bc", ["reward"])
    assert again["method"].tolist() == ["x"]
    with pytest.raises(ValueError, match="baseline"):
        paired_crossed(episodes, "nope", ["reward"])


def _episode(seed: int = 0, T: int = 30):
    from safe_bc.data.episode import Episode

    rng = np.random.default_rng(seed)
    return Episode(
        0, 1, np.zeros((T, 0)), rng.normal(size=(T, 3)), np.zeros((T, 3)),
        rng.normal(size=T).astype(np.float32), np.zeros(T, bool), np.zeros(T, bool),
        (rng.random((T, 3)) * 10).astype(np.float32), (rng.random((T, 3)) * 10).astype(np.float32),
        np.arange(T) < 3, rng.random(T) < 0.2,
        final_cost=(rng.random(3) * 10).astype(np.float32),
    )  # fmt: skip


def test_outcome_violations_count_the_state_each_step_led_to() -> None:
    """``violating_sessions`` counts the outcomes (next step's cost, the last step's
    ``final_cost``), which ``violation_steps`` (the state each step starts from) misses for the
    last step; the zoom-in's outcomes are left out; NaN without a ``final_cost``."""
    from dataclasses import replace

    from safe_bc.data.episode import Episode
    from safe_bc.metrics import episode_metrics

    T = 4
    costs = np.array([[0, 0, 0], [5, 0, 0], [0, 0, 0], [0, 0, 0]], np.float32)
    ep = Episode(
        0, 1, np.zeros((T, 0)), np.zeros((T, 3)), np.zeros((T, 3)), np.ones(T, np.float32),
        np.zeros(T, bool), np.zeros(T, bool), np.zeros((T, 3), np.float32), costs,
        np.zeros(T, bool), np.zeros(T, bool), final_cost=np.array([0, 0, 9], np.float32),
    )  # fmt: skip
    limits = np.array([1.0, 1.0, 1.0])
    m = episode_metrics(ep, thresholds=limits)
    assert (m["violation_steps"], m["violating_sessions"]) == (1, 2)
    assert (m["any_violating_session"], m["last_session_violation"]) == (1.0, 1.0)
    zoom = replace(ep, warmup=np.array([True, True, False, False]))  # step 0's outcome: zoom-in
    assert episode_metrics(zoom, thresholds=limits)["violating_sessions"] == 1
    assert np.isnan(episode_metrics(replace(ep, final_cost=None), thresholds=limits)[
        "violating_sessions"])  # fmt: skip


def test_an_episode_that_ends_by_crossing_d_s_counts_as_beyond() -> None:
    """An episode whose last step crosses ``d_s`` (a plug-in's lane ends at the edge) reached a
    state beyond it: ``any_violation`` counts it beside ``any_violating_session``, though no
    step started beyond ``d_s`` (``violation_steps`` 0)."""
    from safe_bc.data.episode import Episode
    from safe_bc.metrics import episode_metrics, episodes_beyond

    T = 3
    ep = Episode(
        0, 1, np.zeros((T, 0)), np.zeros((T, 1)), np.zeros((T, 1)), np.ones(T, np.float32),
        np.array([False, False, True]), np.zeros(T, bool), np.ones((T, 2), np.float32),
        np.zeros((T, 2), np.float32), np.zeros(T, bool), np.zeros(T, bool), ("left", "right"),
        final_cost=np.array([0, 3], np.float32),
    )  # fmt: skip
    m = episode_metrics(ep, thresholds=np.array([1.0, 1.0]))
    assert m["violation_steps"] == 0 and m["any_violating_session"] == 1.0
    assert m["any_violation"] == 1.0
    assert episodes_beyond(pd.DataFrame([m])).tolist() == [True]


def test_a_metric_that_is_not_general_is_the_named_tasks_only() -> None:
    """``own`` (a task's ``TaskSpec.metrics``): a metric that is not general and not named is
    NaN; ``None`` measures every metric."""
    from safe_bc.metrics import episode_metrics

    ep, limits = _episode(), np.array([7.0, 8.0, 9.0])
    every = episode_metrics(ep, thresholds=limits)
    assert np.isfinite(every["steer_autocorr"])
    mine = episode_metrics(ep, thresholds=limits, own=("steer_change",))
    assert np.isnan(mine["steer_autocorr"]) and mine["steer_change"] == every["steer_change"]
    assert mine["reward"] == every["reward"]


@pytest.mark.parametrize("name", list(__import__("safe_bc.metrics").metrics.REGISTRY))
def test_registry_entries_are_complete(name: str) -> None:
    """Every registered metric says what it measures and gives one finite number per
    episode, reported by every evaluation (``episode_metrics``) in the registry's order."""
    from safe_bc.metrics import METRICS, REGISTRY, episode_metrics

    metric = REGISTRY[name]
    assert metric.doc.strip(), f"metric {name!r} has no doc"
    m = episode_metrics(_episode(), thresholds=np.array([7.0, 8.0, 9.0]), tiles_visited=4.0)
    assert np.isfinite(float(m[name]))
    assert list(m)[: len(METRICS)] == list(METRICS)
    if metric.needs_limits:  # without d_s a limit metric is NaN, not a made-up number
        assert np.isnan(episode_metrics(_episode())[name])


def test_a_new_metric_is_one_entry(monkeypatch: pytest.MonkeyPatch) -> None:
    from safe_bc import metrics

    entry = metrics.Metric(lambda s: float(s.costs.max()), "the largest scored cost")
    monkeypatch.setitem(metrics.REGISTRY, "max_cost", entry)
    ep = _episode()
    assert metrics.episode_metrics(ep)["max_cost"] == pytest.approx(ep.costs[3:].max())


def _bootstrap_loop(values: np.ndarray, groups: np.ndarray, rng: np.random.Generator) -> tuple:
    """The two-level loop ``bootstrap_ci`` ran for every case before its i.i.d. fast path."""
    labels = np.unique(groups)
    members = [values[groups == g] for g in labels]
    boots = np.empty(2000)
    for b in range(2000):
        picked = rng.integers(0, len(members), len(members))
        parts = [members[i][rng.integers(0, len(members[i]), len(members[i]))] for i in picked]
        boots[b] = np.concatenate(parts).mean()
    lo, hi = np.quantile(boots, [0.025, 0.975])
    return float(values.mean()), float(lo), float(hi)


@pytest.mark.parametrize("n", [2, 3, 7, 17, 51])
def test_iid_fast_path_gives_the_two_level_loops_interval_bit_for_bit(n: int) -> None:
    values = np.random.default_rng(n).normal(900, 30, n)
    labels = np.random.default_rng(n + 1).permutation(n) * 3  # one value per group, any labels
    for groups in (None, labels):
        fast = bootstrap_ci(values, groups, rng=np.random.default_rng(7))
        slow = _bootstrap_loop(values, np.arange(n) if groups is None else labels,
                               np.random.default_rng(7))  # fmt: skip
        assert fast == slow
