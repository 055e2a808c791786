"""Property tests for safe_bc.selection (thresholds, T_eps, mixed batches)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from safe_bc.selection import (
    MixedBatchSampler,
    SelectionConfig,
    SelectionError,
    critical_dims,
    critical_mask,
    n_critical_per_batch,
    select,
    thresholds,
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
