"""Property tests for safe_bc.selection (thresholds, T_eps, mixed batches)."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from safe_bc.selection import (
    CriticalSubsetWarning,
    MixedBatchSampler,
    SelectionConfig,
    SelectionError,
    WeightedBatchSampler,
    cost_weights,
    critical_dims,
    critical_mask,
    improper_subset_message,
    limit_margins,
    n_critical_per_batch,
    safe_segment_rows,
    segment_ids,
    select,
    thresholds,
    warn_if_improper_subset,
)

FAST = settings(max_examples=60, deadline=None)

alphas = st.floats(0.0, 1.0, allow_nan=False)
epsilons = st.floats(0.0, 50.0, allow_nan=False)


@st.composite
def cost_data(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray]:
    """``(costs (N, S) float32, valid (N,) bool)`` with at least one valid row."""
    n = draw(st.integers(1, 40))
    s = draw(st.integers(1, 4))
    elems = st.floats(-100, 100, width=32, allow_nan=False, allow_infinity=False)
    costs = draw(hnp.arrays(np.float32, (n, s), elements=elems))
    valid = draw(hnp.arrays(np.bool_, n))
    valid[draw(st.integers(0, n - 1))] = True
    return costs, valid


def brute_force_mask(costs, valid, eps, combine):
    """Eq. 4 by loops: ``d_s = max over valid rows``; ``c_s >= d_s - eps``."""
    n, s = costs.shape
    d = [max(float(costs[i, j]) for i in range(n) if valid[i]) for j in range(s)]
    out = []
    for i in range(n):
        flags = [valid[i] and float(costs[i, j]) >= d[j] - eps for j in range(s)]
        out.append(valid[i] and (any(flags) if combine == "any" else all(flags)))
    return np.array(out, bool)


@st.composite
def sampler_args(draw: st.DrawFn):
    n = draw(st.integers(1, 30))
    mask = draw(hnp.arrays(np.bool_, n))
    valid = draw(hnp.arrays(np.bool_, n))
    alpha = draw(alphas)
    batch = draw(st.integers(1, 70))
    rest = draw(st.sampled_from(["all", "noncritical"]))
    return mask, valid, alpha, batch, rest


def _feasible(mask, valid, alpha, rest):
    crit = (mask & valid).any()
    pool = valid.any() if rest == "all" else (valid & ~mask).any()
    return (alpha == 0 or crit) and (alpha == 1 or pool)


# --- thresholds and T_eps ---------------------------------------------------------------


@FAST
@given(cost_data(), epsilons, st.sampled_from(["any", "all"]))
def test_mask_matches_brute_force(data, eps, combine):
    costs, valid = data
    d = thresholds(costs, "max", valid=valid)
    got = critical_mask(costs, d, eps, combine, valid)
    np.testing.assert_array_equal(got, brute_force_mask(costs, valid, eps, combine))


@FAST
@given(cost_data(), epsilons, epsilons)
def test_mask_monotone_in_eps(data, e1, e2):
    costs, valid = data
    lo, hi = sorted((e1, e2))
    d = thresholds(costs, valid=valid)
    small = critical_mask(costs, d, lo, "any", valid)
    big = critical_mask(costs, d, hi, "any", valid)
    assert not (small & ~big).any()


@FAST
@given(cost_data(), epsilons)
def test_all_subset_of_any_and_invalid_never_critical(data, eps):
    costs, valid = data
    d = thresholds(costs, valid=valid)
    m_all = critical_mask(costs, d, eps, "all", valid)
    m_any = critical_mask(costs, d, eps, "any", valid)
    assert not (m_all & ~m_any).any()
    assert not m_any[~valid].any()
    assert not critical_dims(costs, d, eps, valid)[~valid].any()


@FAST
@given(cost_data(), st.floats(0.01, 1.0))
def test_quantile_threshold_at_most_max(data, q):
    costs, valid = data
    assert (thresholds(costs, "quantile", q, valid) <= thresholds(costs, "max", valid=valid)).all()


@FAST
@given(cost_data())
def test_eps_zero_keeps_the_argmax_rows(data):
    costs, valid = data
    sel = select(costs, SelectionConfig(eps=0.0), valid)
    # every dimension's worst valid row is critical in that dimension
    for s in range(costs.shape[1]):
        worst = np.flatnonzero(valid)[np.argmax(costs[valid, s])]
        assert sel.per_dim[worst, s]


def test_warmup_rows_never_selected_nor_set_threshold():
    costs = np.array([[100.0], [1.0], [2.0], [3.0]], np.float32)
    valid = np.array([False, True, True, True])
    sel = select(costs, SelectionConfig(eps=1.0, alpha=1.0), valid)
    assert sel.thresholds.tolist() == [3.0]
    assert sel.mask.tolist() == [False, False, True, True]
    sampler = sel.sampler(256, np.random.default_rng(0))
    assert not np.isin(sampler.sample(), [0]).any()


def test_selection_summary_is_json():
    rng = np.random.default_rng(1)
    costs = rng.uniform(0, 40, (50, 3)).astype(np.float32)
    valid = np.arange(50) >= 5
    sel = select(costs, SelectionConfig(eps=5.0), valid, ("left", "front", "right"))
    summary = json.loads(json.dumps(sel.to_dict()))
    assert summary["n_rows"] == 50 and summary["n_valid"] == 45
    assert summary["n_critical"] == int(sel.mask.sum()) > 0
    assert summary["critical_per_dim"] == sel.per_dim.sum(0).tolist()
    assert summary["config"]["eps"] == 5.0 and summary["safety_dims"][1] == "front"
    assert np.allclose(summary["thresholds"], costs[valid].max(0))


# --- the sampler ------------------------------------------------------------------------


@FAST
@given(sampler_args(), st.integers(0, 2**32 - 1))
def test_batch_composition(args, seed):
    mask, valid, alpha, batch, rest = args
    if not _feasible(mask, valid, alpha, rest):
        with pytest.raises(SelectionError):
            MixedBatchSampler(mask, alpha, batch, rest, np.random.default_rng(seed), valid)
        return
    sampler = MixedBatchSampler(mask, alpha, batch, rest, np.random.default_rng(seed), valid)
    k = int(np.floor(alpha * batch + 0.5))
    crit, other = sampler.sample_parts()
    assert len(crit) == k and len(other) == batch - k
    assert mask[crit].all() and valid[crit].all() and valid[other].all()
    idx = sampler.sample()
    assert idx.shape == (batch,) and idx.dtype == np.int64
    assert valid[idx].all()
    if rest == "noncritical":
        assert not mask[other].any()
        assert int(mask[idx].sum()) == k
    else:
        assert int(mask[idx].sum()) >= k


@FAST
@given(sampler_args(), st.integers(0, 2**32 - 1))
def test_same_seed_same_batches(args, seed):
    mask, valid, alpha, batch, rest = args
    if not _feasible(mask, valid, alpha, rest):
        return
    a = MixedBatchSampler(mask, alpha, batch, rest, np.random.default_rng(seed), valid)
    b = MixedBatchSampler(mask, alpha, batch, rest, np.random.default_rng(seed), valid)
    for _ in range(3):
        np.testing.assert_array_equal(a.sample(), b.sample())


def test_with_rng_restarts_the_stream():
    mask = np.arange(20) % 3 == 0
    s = MixedBatchSampler(mask, 0.5, 8, "all", np.random.default_rng(7))
    first = [s.sample() for _ in range(2)]
    again = s.with_rng(np.random.default_rng(7))
    np.testing.assert_array_equal(first[0], again.sample())
    np.testing.assert_array_equal(first[1], again.sample())


def test_batches_are_shuffled_and_cover_pools():
    mask = np.zeros(100, bool)
    mask[:10] = True
    s = MixedBatchSampler(mask, 0.5, 64, "noncritical", np.random.default_rng(0))
    batches = np.stack([s.sample() for _ in range(200)])
    # critical positions are not always the first k slots
    assert not mask[batches[:, : s.n_critical]].all()
    assert set(batches.ravel()) == set(range(100))


def test_round_half_up():
    assert n_critical_per_batch(0.5, 3) == 2  # Python round(1.5) == 2 too
    assert n_critical_per_batch(0.5, 5) == 3  # round(2.5) == 2 (banker's); we take 3
    assert n_critical_per_batch(0.0, 64) == 0 and n_critical_per_batch(1.0, 64) == 64


def test_alpha_zero_rest_all_is_plain_bc():
    mask = np.zeros(10, bool)  # empty T_eps is fine when alpha == 0
    s = MixedBatchSampler(mask, 0.0, 32, "all", np.random.default_rng(0))
    assert s.sample().shape == (32,)


# --- errors -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"eps": -1.0}, "eps"),
        ({"eps": float("nan")}, "eps"),
        ({"alpha": 1.5}, "alpha"),
        ({"alpha": -0.1}, "alpha"),
        ({"quantile": 0.0}, "quantile"),
        ({"quantile": 1.01}, "quantile"),
        ({"threshold": "mean"}, "threshold"),
        ({"combine": "some"}, "combine"),
        ({"rest": "none"}, "rest"),
        ({"mode": "weighted"}, "mode"),
        ({"segment_steps": 0}, "segment_steps"),
        ({"segment_steps": 2.5}, "segment_steps"),
        ({"segment_steps": True}, "segment_steps"),
        ({"beta": -1.0}, "beta"),
        ({"beta": float("inf")}, "beta"),
    ],
)
def test_config_validation(kwargs, field):
    with pytest.raises(ValueError, match=field):
        SelectionConfig(**kwargs)


def test_sampler_errors_name_counts():
    mask = np.zeros(5, bool)
    with pytest.raises(SelectionError, match=r"T_eps is empty .*critical=0"):
        MixedBatchSampler(mask, 0.1, 8, "all", np.random.default_rng(0))
    full = np.ones(5, bool)
    with pytest.raises(SelectionError, match=r"rest pool is empty .*noncritical\)=0"):
        MixedBatchSampler(full, 0.5, 8, "noncritical", np.random.default_rng(0))
    with pytest.raises(SelectionError, match="batch_size"):
        MixedBatchSampler(full, 1.0, 0, "all", np.random.default_rng(0))
    with pytest.raises(ValueError, match="alpha"):
        MixedBatchSampler(full, 2.0, 8, "all", np.random.default_rng(0))


def test_data_errors():
    costs = np.ones((3, 2), np.float32)
    with pytest.raises(SelectionError, match="no valid rows"):
        thresholds(costs, valid=np.zeros(3, bool))
    bad = costs.copy()
    bad[1, 0] = np.nan
    with pytest.raises(SelectionError, match="non-finite"):
        thresholds(bad)
    thresholds(bad, valid=np.array([True, False, True]))  # NaN only in an invalid row is fine
    with pytest.raises(ValueError, match="shape"):
        thresholds(np.ones(3, np.float32))
    with pytest.raises(ValueError, match="valid"):
        thresholds(costs, valid=np.ones(3, np.int64))


# --- peer baselines: BC-Safe segments and cost-weighted BC --------------------------------


@st.composite
def episode_data(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """``(episode_ids (N,), valid (N,) bool, mask (N,) bool, K)``; episodes may interleave."""
    n = draw(st.integers(1, 40))
    eps_ids = draw(hnp.arrays(np.int64, n, elements=st.integers(0, 3)))
    valid = draw(hnp.arrays(np.bool_, n))
    mask = draw(hnp.arrays(np.bool_, n)) & valid
    return eps_ids, valid, mask, draw(st.integers(1, 7))


@FAST
@given(episode_data())
def test_segments_are_windows_of_k_consecutive_scored_steps(data):
    episode_ids, valid, _, k = data
    seg = segment_ids(episode_ids, valid, k)
    assert (seg[~valid] == -1).all() and (seg[valid] >= 0).all()
    expected = []  # by loops: each episode's valid rows in row order, cut every k
    for e in sorted(set(episode_ids[valid].tolist())):
        rows = [i for i in range(len(valid)) if valid[i] and episode_ids[i] == e]
        expected += [rows[j : j + k] for j in range(0, len(rows), k)]
    got = (
        [np.flatnonzero(seg == s).tolist() for s in range(int(seg.max()) + 1)]
        if valid.any()
        else []
    )
    assert got == expected


@FAST
@given(episode_data())
def test_safe_segment_rows_match_brute_force(data):
    episode_ids, valid, mask, k = data
    seg = segment_ids(episode_ids, valid, k)
    kept = safe_segment_rows(mask, seg)
    for i in range(len(valid)):
        same = seg == seg[i]
        assert kept[i] == (valid[i] and not mask[same].any())
    assert not (kept & mask).any()


def test_bc_safe_keeps_the_segments_that_never_enter_t_eps():
    # two episodes of 6 scored steps (after a warm-up row each); d = 10, eps = 1: cost >= 9
    costs = np.array([[50], [1], [2], [9], [3], [1], [2], [50], [1], [1], [1], [1], [1], [10.0]])
    valid = np.array([False] + [True] * 6 + [False] + [True] * 6)
    episodes = np.repeat([0, 1], 7)
    cfg = SelectionConfig(eps=1.0, mode="bc_safe", segment_steps=2)
    sel = select(costs, cfg, valid, episode_ids=episodes)
    assert sel.thresholds.tolist() == [10.0]
    assert np.flatnonzero(sel.mask).tolist() == [3, 13]
    # segments: ep 0 rows (1,2) (3,4) (5,6); ep 1 rows (8,9) (10,11) (12,13)
    assert sel.segments.tolist() == [-1, 0, 0, 1, 1, 2, 2, -1, 3, 3, 4, 4, 5, 5]
    assert np.flatnonzero(sel.weights).tolist() == [1, 2, 5, 6, 8, 9, 10, 11]
    summary = sel.to_dict()
    assert (summary["n_segments"], summary["n_safe_segments"], summary["n_train_rows"]) == (6, 4, 8)
    assert summary["critical_sample_share"] == 0.0 and summary["mode"] == "bc_safe"
    batches = np.concatenate(
        [sel.sampler(16, np.random.default_rng(s)).sample() for s in range(20)]
    )
    assert set(batches.tolist()) == {1, 2, 5, 6, 8, 9, 10, 11}
    # without episode ids the rows form one episode: the windows straddle the boundary
    one = select(costs, cfg, valid)
    assert one.segments.tolist() == [-1, 0, 0, 1, 1, 2, 2, -1, 3, 3, 4, 4, 5, 5]


def test_bc_safe_with_nothing_left_names_the_problem():
    costs = np.array([[1.0], [9.5], [1.0], [1.0], [10.0], [1.0]])
    episodes = np.repeat([0, 1], 3)
    cfg = SelectionConfig(eps=1.0, mode="bc_safe", segment_steps=3)  # whole episodes
    with pytest.raises(
        SelectionError, match=r"BC-Safe keeps no demonstrations: all 2 segments of 3"
    ):
        select(costs, cfg, episode_ids=episodes)
    ok = select(
        costs, SelectionConfig(eps=1.0, mode="bc_safe", segment_steps=1), episode_ids=episodes
    )
    assert np.flatnonzero(ok.weights).tolist() == [0, 2, 3, 5]


def test_cost_weights_formula():
    # d = (10, 10); margins g = min_s(d_s - c_s): 10, 5, 0 (and 2 beyond the threshold, clipped)
    costs = np.array([[0.0, 0.0], [5.0, 1.0], [2.0, 10.0], [3.0, 3.0]])
    d = np.array([10.0, 10.0])
    assert limit_margins(costs, d).tolist() == [10.0, 5.0, 0.0, 7.0]
    assert limit_margins(costs, d, "all").tolist() == [10.0, 9.0, 8.0, 7.0]
    w = cost_weights(costs, d, 4.0)
    np.testing.assert_allclose(w, [1.0, 3.0, 5.0, 1 + 4 * 0.3])
    valid = np.array([True, True, False, True])
    np.testing.assert_allclose(cost_weights(costs, d, 4.0, valid=valid), [1.0, 3.0, 0.0, 2.2])
    np.testing.assert_allclose(cost_weights(costs, d, 0.0), 1.0)  # beta = 0: plain BC
    beyond = limit_margins(np.array([[12.0]]), np.array([10.0]))
    assert beyond.tolist() == [0.0]


def test_cost_weighted_selection_samples_in_proportion():
    costs = np.array([[0.0], [5.0], [10.0], [99.0]])
    valid = np.array([True, True, True, False])
    sel = select(costs, SelectionConfig(eps=1.0, mode="cost_weighted", beta=4.0), valid)
    np.testing.assert_allclose(sel.weights, [1.0, 3.0, 5.0, 0.0])
    assert sel.to_dict()["critical_sample_share"] == pytest.approx(5 / 9)
    sampler = sel.sampler(9000, np.random.default_rng(3))
    assert isinstance(sampler, WeightedBatchSampler)
    counts = np.bincount(sampler.sample(), minlength=4) / 9000
    np.testing.assert_allclose(counts, [1 / 9, 3 / 9, 5 / 9, 0], atol=0.02)
    with pytest.raises(ValueError, match="alpha applies to mode='mix' only"):
        sel.sampler(8, np.random.default_rng(0), alpha=0.5)


@FAST
@given(cost_data(), st.floats(0.0, 20.0), st.floats(0.0, 20.0), st.sampled_from(["any", "all"]))
def test_cost_weights_properties(data, beta, eps, combine):
    costs, valid = data
    d = thresholds(costs, valid=valid)
    w = cost_weights(costs, d, beta, combine, valid)
    g = limit_margins(costs, d, combine, valid)
    assert (w[~valid] == 0).all()
    assert (w[valid] >= 1 - 1e-9).all() and (w[valid] <= 1 + beta + 1e-9).all()
    # weights fall as the margin to the limit grows (increase with cost)
    order = np.argsort(g[valid], kind="stable")
    assert (np.diff(w[valid][order]) <= 1e-9).all()
    # T_eps is {g <= eps} (up to rounding at the edge), and every row with g <= eps weighs at
    # least as much as every row outside
    crit = critical_mask(costs, d, eps, combine, valid)
    clear = valid & (np.abs(g - eps) > 1e-6 * (1 + np.abs(costs).max()))
    np.testing.assert_array_equal(crit[clear], g[clear] <= eps)
    near = valid & (g <= eps)
    if near.any() and (valid & ~near).any():
        assert w[near].min() >= w[valid & ~near].max()


@FAST
@given(
    hnp.arrays(np.float64, st.integers(1, 30), elements=st.sampled_from([0.0, 0.5, 1.0, 7.0])),
    st.integers(1, 50),
    st.integers(0, 2**32 - 1),
)
def test_weighted_sampler_deterministic_and_never_draws_zero_weight(w, batch, seed):
    if not (w > 0).any():
        with pytest.raises(SelectionError, match="every sampling weight is 0"):
            WeightedBatchSampler(w, batch, np.random.default_rng(seed))
        return
    a = WeightedBatchSampler(w, batch, np.random.default_rng(seed))
    b = WeightedBatchSampler(w, batch, np.random.default_rng(seed))
    for _ in range(3):
        x = a.sample()
        np.testing.assert_array_equal(x, b.sample())
        assert x.shape == (batch,) and x.dtype == np.int64 and (w[x] > 0).all()
    again = a.with_rng(np.random.default_rng(seed))
    first = WeightedBatchSampler(w, batch, np.random.default_rng(seed)).sample()
    np.testing.assert_array_equal(again.sample(), first)


def test_weighted_sampler_errors():
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="finite and >= 0"):
        WeightedBatchSampler(np.array([1.0, -1.0]), 4, rng)
    with pytest.raises(ValueError, match="finite and >= 0"):
        WeightedBatchSampler(np.array([1.0, np.nan]), 4, rng)
    with pytest.raises(ValueError, match="outside valid"):
        WeightedBatchSampler(np.ones(2), 4, rng, valid=np.array([True, False]))
    with pytest.raises(SelectionError, match="batch_size"):
        WeightedBatchSampler(np.ones(2), 0, rng)
    with pytest.raises(TypeError, match="Generator"):
        WeightedBatchSampler(np.ones(2), 4, 0)


def test_a_study_can_search_the_mode():
    from safe_bc.methods.experiment import RunConfig
    from safe_bc.study.spec import apply_params

    cfg = apply_params(
        RunConfig(),
        {"selection.mode": "bc_safe", "selection.segment_steps": 10.0, "selection.beta": 2},
    )
    assert cfg.selection.mode == "bc_safe" and cfg.selection.segment_steps == 10
    assert cfg.selection.beta == 2.0
    with pytest.raises(ValueError, match="mode"):
        apply_params(RunConfig(), {"selection.mode": "osrl"})


def test_every_selection_mode_has_a_complete_rule():
    """The rule registry: one entry per mode, its own fields real config fields, a label, and
    weights of one per row (or None for the mix) on toy demonstrations."""
    import dataclasses
    from typing import get_args

    from safe_bc.selection import RULES, Baseline, SelectionConfig, SelectionMode, select

    assert tuple(RULES) == get_args(SelectionMode)
    assert set(get_args(Baseline)) == set(RULES) - {"mix"}
    fields = {f.name for f in dataclasses.fields(SelectionConfig)}
    rng = np.random.default_rng(0)
    costs = rng.uniform(0, 10, size=(200, 3))
    episodes = np.repeat(np.arange(4), 50)
    for mode, rule in RULES.items():
        assert set(rule.params) <= fields, mode
        cfg = SelectionConfig(eps=1.0, mode=mode, segment_steps=5)
        assert rule.label(cfg).strip()
        sel = select(costs, cfg, episode_ids=episodes)
        if mode == "mix":
            assert sel.weights is None
        else:
            assert sel.weights.shape == (200,) and (sel.weights >= 0).all()


# --- T_eps that is no proper subset -----------------------------------------------------


def _two_dim_costs() -> tuple[np.ndarray, np.ndarray]:
    """10 scored rows (left 0..9, right 9..0) behind 2 warm-up rows of cost 100."""
    left = np.arange(10, dtype=np.float64)
    costs = np.concatenate([np.full((2, 2), 100.0), np.stack([left, 9 - left], 1)])
    return costs, np.arange(12) >= 2


def test_every_row_critical_warns_with_eps_fraction_and_limits():
    costs, valid = _two_dim_costs()
    sel = select(costs, SelectionConfig(eps=20.0, alpha=0.3), valid, ("left", "right"))
    assert sel.n_critical == sel.n_valid == 10
    with pytest.warns(CriticalSubsetWarning) as caught:
        warn_if_improper_subset(sel)
    assert len(caught) == 1
    message = str(caught[0].message)
    assert "\n" not in message
    assert "every scored row (10 of 10, critical fraction 1)" in message
    assert "eps=20" in message and "alpha=0.3 has no effect" in message
    assert "d_s left=9, right=9" in message  # the warm-up rows' 100 set no limit


def test_empty_t_eps_warns_with_alpha_and_names_it():
    costs, valid = _two_dim_costs()
    # combine="all": no scored row is near both limits (left + right = 9)
    sel = select(costs, SelectionConfig(eps=1.0, alpha=1.0, combine="all"), valid)
    assert sel.n_critical == 0
    message = improper_subset_message(sel)
    assert message is not None and "no scored row (0 of 10, critical fraction 0)" in message
    assert "alpha=1 cannot be drawn" in message
    assert "combine='all'" in message and "d_s c0=9, c1=9" in message


@pytest.mark.parametrize(
    "config",
    [
        SelectionConfig(eps=1.0, alpha=0.5),  # a proper subset
        SelectionConfig(eps=20.0, alpha=0.0),  # everything critical, but plain BC anyway
        SelectionConfig(eps=20.0, mode="cost_weighted"),  # the baselines ignore alpha
    ],
)
def test_no_warning_when_the_mix_can_focus_or_alpha_is_unused(config):
    costs, valid = _two_dim_costs()
    sel = select(costs, config, valid)
    assert improper_subset_message(sel) is None
    with warnings.catch_warnings():
        warnings.simplefilter("error", CriticalSubsetWarning)
        warn_if_improper_subset(sel)
