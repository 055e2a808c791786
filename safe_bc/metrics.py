"""Evaluation metrics and confidence intervals (pure numpy/pandas: no I/O, no Ray)."""

from __future__ import annotations

import math
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import pandas as pd

from safe_bc.data.episode import Episode
from safe_bc.selection import DEFAULT_EPS, Combine, critical_mask


@dataclass(frozen=True)
class Scored:
    """What a per-episode metric reads: one episode restricted to its scored steps."""

    episode: Episode
    """The whole episode (reward and length count every step)."""
    safety: np.ndarray
    """``(T', S)`` safety distances of the scored steps (the CarRacing zoom-in excluded)."""
    costs: np.ndarray
    """``(T', S)`` safety costs of the scored steps."""
    offroad: np.ndarray
    """``(T',) bool``: scored steps with all wheels on grass / a safety limit crossed."""
    tiles_visited: float
    """Track tiles the episode visited (NaN where the env has none)."""
    limits: np.ndarray | None
    """The expert's limits ``d_s`` per dimension; ``None``: limit metrics are NaN."""
    eps: float
    """Critical-zone width of ``critical_share``."""
    combine: Combine
    """How ``critical_share`` combines the dimensions."""

    @cached_property
    def combined(self) -> np.ndarray:
        """``(T',)``: each scored step's safety, its smallest distance (:func:`combined`)."""
        return combined(self.safety)

    @cached_property
    def steering(self) -> np.ndarray:
        """``(T',)``: the first action dimension (CarRacing's steering) at the scored steps."""
        return self.episode.actions[~self.episode.warmup, 0]

    @cached_property
    def outcomes_beyond(self) -> np.ndarray:
        """``(T'',) bool``: per step, whether its outcome (the state it led to: the next
        step's cost, and for the last step the episode's ``final_cost``) is beyond ``d_s``;
        outcomes in the CarRacing zoom-in are left out. Empty without a ``final_cost``."""
        assert self.limits is not None
        ep = self.episode
        if ep.final_cost is None:
            return np.zeros(0, bool)
        costs = np.concatenate([ep.costs[1:], np.asarray(ep.final_cost)[None]])
        scored = np.append(~ep.warmup[1:], True)
        return violations(costs[scored], self.limits)

    @cached_property
    def beyond(self) -> np.ndarray:
        """``(T',) bool``: scored steps beyond ``d_s`` in some dimension (needs ``limits``)."""
        assert self.limits is not None
        return violations(self.costs, self.limits)


@dataclass(frozen=True)
class Metric:
    """One registry entry: a per-episode metric, summarised as a mean over episodes."""

    compute: Callable[[Scored], float]
    """The episode's value."""
    doc: str
    """What it measures (units, which steps count)."""
    needs_limits: bool = False
    """NaN when the evaluation has no limits ``d_s``."""
    general: bool = True
    """Measured for every task; ``False``: only for the tasks that name it in their
    ``TaskSpec.metrics`` (NaN for the others, e.g. CarRacing's steering follow-through)."""


REGISTRY: dict[str, Metric] = {
    "reward": Metric(lambda s: s.episode.total_reward, "the episode's summed reward"),
    "safety_mean": Metric(
        lambda s: float(s.combined.mean()),
        "mean over the scored steps of the step's safety (its smallest distance); a "
        "policy's safety mean is the mean of its episodes' means",
    ),
    "safety_std": Metric(lambda s: float(s.combined.std()), "spread of the step safety"),
    "safety_min": Metric(lambda s: float(s.combined.min()), "the closest the episode came"),
    "violation_steps": Metric(
        lambda s: int(s.beyond.sum()),
        "scored steps beyond the expert's limit d_s in any dimension (:func:`violations`)",
        needs_limits=True,
    ),
    "violation_rate": Metric(
        lambda s: float(s.beyond.mean()), "violation steps as a share of the scored steps", True
    ),
    "any_violation": Metric(
        lambda s: float(s.beyond.any() or s.outcomes_beyond.any()),
        "1.0 when the episode reached a state beyond d_s: a scored step's, or a step's outcome, "
        "the last one included (an episode that ends by crossing d_s counts; its mean: the "
        "share of episodes)",
        True,
    ),
    "worst_excursion": Metric(
        lambda s: float(excursion(s.costs, s.limits).max()),
        "how far beyond d_s the worst step went (cost units, 0 if never)",
        True,
    ),
    "violating_sessions": Metric(
        lambda s: int(s.outcomes_beyond.sum()) if s.episode.final_cost is not None else np.nan,
        "steps whose outcome (the state the step led to, the last step's included) is beyond "
        "d_s: on the rehabilitation pathway the sessions beyond d_s, which "
        "``violation_steps`` (the state each step starts from) misses for the last session",
        True,
    ),
    "any_violating_session": Metric(
        lambda s: float(s.outcomes_beyond.any()) if s.episode.final_cost is not None else np.nan,
        "1.0 when a step's outcome was beyond d_s (its mean: the share of episodes)",
        True,
    ),
    "last_session_violation": Metric(
        lambda s: (
            float(violations(np.asarray(s.episode.final_cost)[None], s.limits)[0])
            if s.episode.final_cost is not None
            else np.nan
        ),
        "1.0 when the last step's outcome was beyond d_s (no later state records it)",
        True,
    ),
    "offroad_steps": Metric(
        lambda s: int(s.offroad.sum()),
        "scored steps with all wheels on grass (simulator ground truth, CarRacing)",
    ),
    "critical_share": Metric(
        lambda s: float(critical_zone(s.costs, s.limits, s.eps, s.combine).mean()),
        "share of scored steps inside the critical zone c >= d_s - eps",
        True,
    ),
    "tiles_visited": Metric(lambda s: float(s.tiles_visited), "track tiles visited", general=False),
    "steer_autocorr": Metric(
        lambda s: steering_follow(s.steering)[0],
        "lag-1 autocorrelation of the first action (CarRacing's steering) over the scored "
        "steps: how much the steering follows itself (a copycat cue; NaN if constant)",
        general=False,
    ),
    "steer_change": Metric(
        lambda s: steering_follow(s.steering)[1],
        "mean absolute step-to-step change of the first action over the scored steps",
        general=False,
    ),
    "steps": Metric(lambda s: len(s.episode), "the episode's length in env steps"),
}
"""The metric registry: name -> :class:`Metric`. Every evaluation (expert, evaluate, Table 1,
study trials and the study's final phase) reports every entry, one value per episode. A new
metric is one entry here (its function reads :class:`Scored`); ``tests/test_metrics.py``
walks every entry."""

METRICS: tuple[str, ...] = tuple(REGISTRY)
"""The one metric list, in report order (the registry's keys)."""


def steering_follow(steer: np.ndarray) -> tuple[float, float]:
    """Lag-1 autocorrelation of a steering sequence and its mean absolute change (NaN with
    fewer than 3 steps; the autocorrelation NaN when either lagged series is constant).

    >>> a, c = steering_follow(np.array([0.0, 0.5, 1.0, 0.5, 0.0]))
    >>> round(a, 3), c
    (0.0, 0.5)
    """
    steer = np.asarray(steer, np.float64)
    if len(steer) < 3:
        return float("nan"), float("nan")
    x, y = steer[:-1], steer[1:]
    change = float(np.abs(y - x).mean())
    if x.std() == 0 or y.std() == 0:
        return float("nan"), change
    return float(np.corrcoef(x, y)[0, 1]), change


def combined(safety: np.ndarray) -> np.ndarray:
    """One safety number per step: the smallest distance of the dimensions.

    Args:
        safety: ``(T, S)`` distances (higher is safer).

    Returns:
        ``(T,) float32``.
    """
    return np.min(safety, axis=-1).astype(np.float32)


def critical_zone(
    costs: np.ndarray, thresholds: np.ndarray, eps: float, combine: Combine = "any"
) -> np.ndarray:
    """``(T,) bool``: steps inside the critical zone, by the same rule that selects T_eps
    (:func:`safe_bc.selection.critical_mask`)."""
    return critical_mask(costs, thresholds, eps, combine)


def violations(costs: np.ndarray, limits: np.ndarray) -> np.ndarray:
    """``(T,) bool``: steps beyond the limit in some dimension, ``c_s > d_s``.

    Args:
        costs: ``(T, S)`` safety costs (higher is less safe).
        limits: ``(S,)`` the expert's worst costs ``d_s``.

    >>> violations(np.array([[1.0, 2.0], [3.0, 0.0]]), np.array([2.0, 2.0])).tolist()
    [False, True]
    """
    costs = np.asarray(costs, np.float64)
    limits = np.asarray(limits, np.float64)
    if limits.shape != costs.shape[-1:]:
        raise ValueError(f"limits must have shape {costs.shape[-1:]}, got {limits.shape}")
    return np.any(costs > limits, axis=-1)


def excursion(costs: np.ndarray, limits: np.ndarray) -> np.ndarray:
    """``(T,) float64``: how far each step goes beyond the limit (largest over the
    dimensions of ``c_s - d_s``, 0 when inside)."""
    costs = np.asarray(costs, np.float64)
    return np.maximum(np.max(costs - np.asarray(limits, np.float64), axis=-1), 0.0)


def episode_metrics(
    episode: Episode,
    *,
    tiles_visited: float = float("nan"),
    thresholds: np.ndarray | None = None,
    eps: float = DEFAULT_EPS,
    combine: Combine = "any",
    own: Collection[str] | None = None,
) -> dict[str, float]:
    """Every registered metric of one evaluated episode (:data:`REGISTRY`, in its order) plus
    ``terminated`` and per-dimension safety statistics. ``own``: the task's own metrics
    (``TaskSpec.metrics``); a metric that is not general and not among them is NaN
    (``None``: every metric is measured).

    Safety statistics use the scored steps only (the CarRacing zoom-in is
    excluded). ``thresholds`` are the demonstrations' limits ``d_s`` (worst expert cost
    per dimension): violations are steps beyond them and ``critical_share`` is the share
    of scored steps inside the critical zone of width ``eps``; without thresholds those
    metrics are NaN. ``offroad_steps`` counts the simulator's unsafe events (all wheels on
    grass / a safety limit crossed).

    >>> import numpy as np
    >>> T = 5
    >>> ep = Episode(0, 1, np.zeros((T, 0)), np.zeros((T, 3)), np.zeros((T, 3)),
    ...     np.full(T, 2.0), np.zeros(T, bool), np.zeros(T, bool),
    ...     np.array([[5, 60, 5], [4, 60, 6], [3, 60, 7], [2, 60, 8], [1, 60, 9.]]),
    ...     np.zeros((T, 3)), np.array([1, 0, 0, 0, 0], bool), np.zeros(T, bool))
    >>> m = episode_metrics(ep)
    >>> m["reward"], m["steps"], m["safety_min"], m["safety_left_mean"]
    (10.0, 5, 1.0, 2.5)
    >>> m = episode_metrics(ep, thresholds=np.array([40.0, 6.0, 39.0]))  # costs are all 0
    >>> m["violation_steps"], m["any_violation"], m["worst_excursion"]
    (0, 0.0, 0.0)
    """
    scored = ~episode.warmup
    if not scored.any():
        scored = np.ones(len(episode), bool)
    view = Scored(
        episode, episode.safety[scored], episode.costs[scored], episode.offroad[scored],
        float(tiles_visited), thresholds, eps, combine,
    )  # fmt: skip
    nan = float("nan")
    skip = set() if own is None else {k for k, m in REGISTRY.items() if not m.general} - set(own)
    out: dict[str, float] = {
        name: nan if (m.needs_limits and thresholds is None) or name in skip else m.compute(view)
        for name, m in REGISTRY.items()
    }
    out["terminated"] = bool(episode.terminated[-1])
    for j, d in enumerate(episode.safety_dims):
        out[f"safety_{d}_mean"] = float(view.safety[:, j].mean())
        out[f"safety_{d}_std"] = float(view.safety[:, j].std())
        out[f"safety_{d}_min"] = float(view.safety[:, j].min())
    return out


def bootstrap_ci(
    values: np.ndarray,
    groups: np.ndarray | None = None,
    *,
    confidence: float = 0.95,
    n_boot: int = 2000,
    rng: np.random.Generator,
) -> tuple[float, float, float]:
    """Mean and percentile-bootstrap confidence interval, two-level when ``groups`` is given.

    With groups (e.g. training seeds), each replicate resamples the groups with
    replacement and then the values within each chosen group, so both the spread
    between training runs and between evaluation episodes count.

    Hand-written on purpose, also for i.i.d. values: ``scipy.stats.bootstrap`` (percentile,
    the same generator) draws the same resamples, but averages each one along an axis of a
    ``(n_boot, N)`` array instead of one concatenated draw, which rounds differently: on the
    committed expert table (``results/expert/``, 15 metrics x 50 episodes) 4 of its 15
    intervals moved in the last bits (up to 1e-13). The committed tables re-derive bit for bit
    from this loop, and the i.i.d. case is the two-level one with groups of one value.

    Args:
        values: ``(N,)`` observations (one per evaluation episode).
        groups: ``(N,)`` group label per value, or ``None`` for i.i.d. values.

    Returns:
        ``(mean, low, high)``; ``low == high == mean`` for a single value.

    >>> rng = np.random.default_rng(0)
    >>> m, lo, hi = bootstrap_ci(np.arange(10.0), rng=rng)
    >>> m, bool(lo < m < hi)
    (4.5, True)
    """
    values = np.asarray(values, dtype=np.float64)
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    if len(values) == 0:
        return (float("nan"),) * 3
    mean = float(values.mean())
    if len(values) == 1:
        return mean, mean, mean
    boots = bootstrap_means(values, groups, n_boot=n_boot, rng=rng)
    tail = (1 - confidence) / 2
    lo, hi = np.quantile(boots, [tail, 1 - tail])
    return mean, float(lo), float(hi)


def bootstrap_means(
    values: np.ndarray, groups: np.ndarray | None = None, *, n_boot: int, rng: np.random.Generator
) -> np.ndarray:
    """``(n_boot,)`` bootstrap means of ``values (N,)``, two-level when ``groups`` is given:
    each replicate resamples the groups (in label order) with replacement, then the values
    within each chosen group (:func:`bootstrap_ci`'s draws; for a difference of two
    bootstraps, subtract their draws)."""
    values = np.asarray(values, dtype=np.float64)
    if groups is None:
        groups = np.arange(len(values))
    labels = np.unique(groups)
    members = [values[groups == g] for g in labels]
    boots = np.empty(n_boot)
    if all(len(m) == 1 for m in members):  # i.i.d.: the same draws, one indexing per replicate
        flat = np.concatenate(members)  # (a one-value group's inner draw consumes no bits)
        for b in range(n_boot):
            boots[b] = flat[rng.integers(0, len(flat), len(flat))].mean()
    else:
        for b in range(n_boot):
            picked = rng.integers(0, len(members), len(members))
            parts = [members[i][rng.integers(0, len(members[i]), len(members[i]))] for i in picked]
            boots[b] = np.concatenate(parts).mean()
    return boots


def summarize(
    episodes: pd.DataFrame,
    by: Sequence[str],
    metrics: Sequence[str],
    *,
    group: str | None = "train_seed",
    confidence: float = 0.95,
    seed: int = 0,
) -> pd.DataFrame:
    """One row per ``by`` combination: ``<metric>`` mean, ``<metric>_lo``/``_hi`` CI, ``n``.

    Args:
        episodes: one row per evaluated episode.
        by: columns that identify a configuration (e.g. ``alpha``, ``rest``).
        metrics: metric columns to summarise.
        group: column of the training seed (two-level bootstrap), or ``None``.
    """
    rng = np.random.default_rng(seed)
    rows = []
    for key, df in episodes.groupby(list(by), sort=True, dropna=False):
        row = dict(zip(by, key if isinstance(key, tuple) else (key,), strict=True))
        row["n_episodes"] = len(df)
        if group is not None and group in df:
            row["n_train_seeds"] = int(df[group].nunique())
            g = df[group].to_numpy()
        else:
            g = None
        for m in metrics:
            mean, lo, hi = bootstrap_ci(df[m].to_numpy(float), g, confidence=confidence, rng=rng)
            row[m], row[f"{m}_lo"], row[f"{m}_hi"] = mean, lo, hi
        rows.append(row)
    return pd.DataFrame(rows)


def summarize_policies(
    episodes: pd.DataFrame,
    by: Sequence[str] = ("policy",),
    *,
    metrics: Sequence[str] = METRICS,
    group: str | None = None,
    confidence: float = 0.95,
    seed: int = 0,
) -> pd.DataFrame:
    """The one summary of evaluated policies: per ``by`` group, the mean over episodes of every
    metric of :data:`METRICS` present (NaN-only metrics dropped) and the per-dimension safety
    means, with a bootstrap CI, ``n_episodes`` and ``episodes_with_violation``.

    Args:
        episodes: one row per evaluated episode (``evaluate_policies`` output).
        group: column of the training seed when each seed was evaluated on its own tracks
            (a nested design: two-level bootstrap, seeds then tracks); ``None``: episodes
            are resampled i.i.d.
    """
    present = [m for m in metrics if m in episodes and episodes[m].notna().any()]
    present += [c for c in episodes.columns if c.startswith("safety_") and c.endswith("_mean")]
    present = list(dict.fromkeys(present))
    table = summarize(episodes, list(by), present, group=group, confidence=confidence, seed=seed)
    if "any_violation" in present:
        counts = episodes.groupby(list(by), sort=True, dropna=False)["any_violation"].sum()
        table["episodes_with_violation"] = counts.to_numpy().astype(int)
    return table


def mean_metrics(episodes: pd.DataFrame, metrics: Sequence[str] = METRICS) -> dict[str, float]:
    """Means over the episodes of one policy (a study trial's result), same definitions as
    :func:`summarize_policies` (per-dimension safety means included); missing metrics are NaN."""
    dims = [c for c in episodes.columns if c.startswith("safety_") and c.endswith("_mean")]
    names = [*metrics, *dims]
    return {
        m: float(episodes[m].astype(float).mean()) if m in episodes else float("nan")
        for m in dict.fromkeys(names)
    }


def paired_differences(
    episodes: pd.DataFrame,
    baseline: str,
    metrics: Sequence[str],
    *,
    by: str = "method",
    pair_on: Sequence[str] = ("train_seed", "env_seed"),
    group: str = "train_seed",
    confidence: float = 0.95,
    seed: int = 0,
) -> pd.DataFrame:
    """Per method, the mean difference to ``baseline`` on the same (training seed, track)
    pairs, with a two-level bootstrap CI: ``d_<metric>``, ``d_<metric>_lo``, ``d_<metric>_hi``.
    For a nested design (each seed on its own tracks); each interval draws from its own
    generator (:func:`keyed_rng` of ``seed``, the method and baseline, and the metric).

    Pairing removes the spread between tracks, which dominates single-method CIs.
    Methods without a matching pair (e.g. the expert, trained once) are left out.

    >>> df = pd.DataFrame({"method": ["a", "a", "b", "b"], "train_seed": [0, 0, 0, 0],
    ...                    "env_seed": [1, 2, 1, 2], "reward": [10.0, 20.0, 12.0, 23.0]})
    >>> paired_differences(df, "a", ["reward"])[["method", "d_reward"]].to_dict("records")
    [{'method': 'b', 'd_reward': 2.5}]
    """
    key = list(pair_on)
    base = episodes[episodes[by] == baseline].set_index(key)[list(metrics)]
    rows = []
    for method, df in episodes.groupby(by, sort=False):
        if method == baseline:
            continue
        diff = (df.set_index(key)[list(metrics)] - base).dropna()
        if diff.empty:
            continue
        groups = diff.index.get_level_values(group).to_numpy()
        row: dict[str, object] = {by: method, "n_pairs": len(diff)}
        for m in metrics:
            rng = keyed_rng(seed, (method, baseline), m)
            mean, lo, hi = bootstrap_ci(
                diff[m].to_numpy(float), groups, confidence=confidence, rng=rng
            )
            row[f"d_{m}"], row[f"d_{m}_lo"], row[f"d_{m}_hi"] = mean, lo, hi
        rows.append(row)
    return pd.DataFrame(rows)


def crossed_bootstrap_ci(
    cells: np.ndarray,
    *,
    confidence: float = 0.95,
    n_boot: int = 2000,
    rng: np.random.Generator,
) -> tuple[float, float, float]:
    """Mean of a crossed ``(training seeds, tracks)`` table with a crossed bootstrap CI.

    In Table 1 every agent of every method is evaluated on the *same* held-out tracks
    (``env_seed``) and the training seeds are shared too: a cell ``(s, t)`` is the metric of
    seed ``s``'s agent on track ``t``. Each replicate draws the seeds (rows) with replacement
    and, independently, the tracks (columns) with replacement, and averages the chosen
    seeds x chosen tracks cells (missing cells, NaN, are skipped). The nested two-level
    bootstrap (:func:`bootstrap_ci` with groups: seeds, then episodes within each seed) draws
    every seed's tracks separately, as if each seed had its own tracks; with shared tracks a
    hard track is hard for every seed at once, so the nested bootstrap averages that
    variation away (by a factor of the number of seeds) and its intervals under-cover, the
    more so the fewer seeds there are.

    Args:
        cells: ``(S, T)`` values, ``NaN`` where a cell was not evaluated.
        confidence: in ``(0, 1)``.
        n_boot: bootstrap replicates.
        rng: the only source of randomness.

    Returns:
        ``(mean over the cells, low, high)``; ``low == high == mean`` for a single cell, NaN
        for no cell.

    >>> cells = np.array([[1.0, 5.0], [2.0, 6.0]])
    >>> m, lo, hi = crossed_bootstrap_ci(cells, rng=np.random.default_rng(0))
    >>> m, bool(1.0 <= lo <= m <= hi <= 6.0)
    (3.5, True)
    """
    cells = np.asarray(cells, np.float64)
    if cells.ndim != 2:
        raise ValueError(f"cells must be a (seeds, tracks) array, got shape {cells.shape}")
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    if n_boot < 1:
        raise ValueError(f"n_boot must be >= 1, got {n_boot}")
    present = ~np.isnan(cells)
    if not present.any():
        return (float("nan"),) * 3
    mean = float(cells[present].mean())
    if present.sum() == 1:
        return mean, mean, mean
    n_s, n_t = cells.shape
    filled = np.where(present, cells, 0.0)
    boots = np.empty(n_boot)
    chunk = max(1, 2_000_000 // max(n_s * n_t, 1))
    for start in range(0, n_boot, chunk):
        b = min(chunk, n_boot - start)
        si = rng.integers(0, n_s, (b, n_s))
        ti = rng.integers(0, n_t, (b, n_t))
        pick = (si[:, :, None], ti[:, None, :])
        total = filled[pick].sum(axis=(1, 2))
        count = present[pick].sum(axis=(1, 2))
        with np.errstate(invalid="ignore", divide="ignore"):
            boots[start : start + b] = total / count
    tail = (1 - confidence) / 2
    lo, hi = np.nanquantile(boots, [tail, 1 - tail])
    return mean, float(lo), float(hi)


def keyed_rng(seed: int, key: object, metric: str) -> np.random.Generator:
    """A generator for one interval: seeded by ``seed``, a stable hash (CRC-32) of ``repr(key)``
    (a table row's key, e.g. its method) and of ``metric``; the same arguments give the same
    draws in any table and any process.

    >>> a, b = keyed_rng(0, "a", "reward"), keyed_rng(0, "a", "reward")
    >>> int(a.integers(1000)) == int(b.integers(1000))
    True
    """
    import zlib

    return np.random.default_rng(
        [seed, zlib.crc32(repr(key).encode()), zlib.crc32(metric.encode())]
    )


def cell_table(
    episodes: pd.DataFrame, metric: str, *, seeds: str = "train_seed", tracks: str = "env_seed"
) -> pd.DataFrame:
    """``(training seeds, tracks)`` table of one metric (rows sorted seeds, columns sorted
    tracks; the mean where a cell has several episodes, NaN where it has none)."""
    return episodes.pivot_table(index=seeds, columns=tracks, values=metric, aggfunc="mean")


def summarize_crossed(
    episodes: pd.DataFrame,
    by: Sequence[str],
    metrics: Sequence[str],
    *,
    seeds: str = "train_seed",
    tracks: str = "env_seed",
    confidence: float = 0.95,
    n_boot: int = 2000,
    seed: int = 0,
) -> pd.DataFrame:
    """One row per ``by`` combination: ``<metric>`` mean over its ``(seed, track)`` cells with a
    crossed bootstrap CI (:func:`crossed_bootstrap_ci`), ``<metric>_lo``/``_hi``,
    ``n_episodes``, ``n_train_seeds`` and ``n_tracks``.

    Use it instead of :func:`summarize` when every configuration's agents were evaluated on
    the same tracks (Table 1): see :func:`crossed_bootstrap_ci` for why. Each (row, metric)
    draws from its own generator, seeded by ``seed``, the row's key and the metric
    (:func:`keyed_rng`), so the same episodes give the same interval in every table,
    whatever else the table holds.
    """
    rows = []
    for key, df in episodes.groupby(list(by), sort=True, dropna=False):
        row: dict[str, object] = dict(
            zip(by, key if isinstance(key, tuple) else (key,), strict=True)
        )
        row["n_episodes"] = len(df)
        row["n_train_seeds"] = int(df[seeds].nunique())
        row["n_tracks"] = int(df[tracks].nunique())
        for m in metrics:
            cells = cell_table(df, m, seeds=seeds, tracks=tracks).to_numpy(float)
            mean, lo, hi = crossed_bootstrap_ci(
                cells, confidence=confidence, n_boot=n_boot, rng=keyed_rng(seed, key, m)
            )
            row[m], row[f"{m}_lo"], row[f"{m}_hi"] = mean, lo, hi
        rows.append(row)
    return pd.DataFrame(rows)


def paired_crossed(
    episodes: pd.DataFrame,
    baseline: str,
    metrics: Sequence[str],
    *,
    by: str = "method",
    seeds: str = "train_seed",
    tracks: str = "env_seed",
    better: str | None = "reward",
    confidence: float = 0.95,
    n_boot: int = 2000,
    seed: int = 0,
) -> pd.DataFrame:
    """Per method, the mean difference to ``baseline`` on the same ``(training seed, track)``
    cells with a crossed bootstrap CI: ``d_<metric>``, ``d_<metric>_lo``, ``d_<metric>_hi``.

    The difference table ``D[s, t] = method[s, t] - baseline[s, t]`` keeps the seeds and
    tracks both have; it is resampled like :func:`crossed_bootstrap_ci` (seeds and tracks
    independently), so a track effect shared by all methods cancels exactly. ``n_pairs`` is the
    number of cells. With ``better`` (a metric where higher is better, e.g. reward):
    ``seeds_better`` counts the shared training seeds whose mean over the shared tracks beats
    the baseline's same seed (``mean_t D[s, t] > 0``) out of ``n_seeds_paired``. Methods
    without a shared cell (e.g. an expert trained once under another seed) are left out.

    Each (method, metric) draws from its own generator (:func:`keyed_rng` of ``seed``, the
    method, the baseline and the metric): a comparison's interval does not depend on which
    other methods the table holds.

    >>> df = pd.DataFrame({"method": ["a", "a", "b", "b"], "train_seed": [0, 0, 0, 0],
    ...                    "env_seed": [1, 2, 1, 2], "reward": [10.0, 20.0, 12.0, 23.0]})
    >>> out = paired_crossed(df, "a", ["reward"])
    >>> out[["method", "d_reward", "seeds_better", "n_seeds_paired"]].to_dict("records")
    [{'method': 'b', 'd_reward': 2.5, 'seeds_better': 1, 'n_seeds_paired': 1}]
    """
    names = list(dict.fromkeys([*metrics, *([better] if better else [])]))
    base = episodes[episodes[by] == baseline]
    if base.empty:
        raise ValueError(f"baseline {baseline!r} has no episodes in column {by!r}")
    base_cells = {m: cell_table(base, m, seeds=seeds, tracks=tracks) for m in names}
    rows = []
    for method, df in episodes.groupby(by, sort=True):
        if method == baseline:
            continue
        diffs = {}
        for m in names:
            mine = cell_table(df, m, seeds=seeds, tracks=tracks)
            ref = base_cells[m]
            rows_, cols = mine.index.intersection(ref.index), mine.columns.intersection(ref.columns)
            diffs[m] = (mine.loc[rows_, cols] - ref.loc[rows_, cols]).to_numpy(float)
        first = diffs[names[0]]
        n_pairs = int((~np.isnan(first)).sum())
        if n_pairs == 0:
            continue
        row: dict[str, object] = {by: method, "n_pairs": n_pairs}
        for m in metrics:
            mean, lo, hi = crossed_bootstrap_ci(
                diffs[m], confidence=confidence, n_boot=n_boot,
                rng=keyed_rng(seed, (method, baseline), m),
            )  # fmt: skip
            row[f"d_{m}"], row[f"d_{m}_lo"], row[f"d_{m}_hi"] = mean, lo, hi
        if better:
            d = diffs[better]
            has = ~np.isnan(d).all(axis=1)
            with np.errstate(invalid="ignore"):
                per_seed = np.nanmean(np.where(has[:, None], d, 0.0), axis=1)
            row["seeds_better"] = int((per_seed[has] > 0).sum())
            row["n_seeds_paired"] = int(has.sum())
        rows.append(row)
    return pd.DataFrame(rows)


def paired_to_reference(
    episodes: pd.DataFrame,
    reference: str,
    metrics: Sequence[str],
    *,
    by: str = "method",
    seeds: str = "train_seed",
    **kwargs: object,
) -> pd.DataFrame:
    """:func:`paired_crossed` against a policy evaluated once on the same tracks (e.g. the
    expert, not trained per seed): its episode on each track stands beside every training
    seed's, so ``D[s, t] = method[s, t] - reference[t]``, resampled over seeds and tracks.

    >>> df = pd.DataFrame({"method": ["e", "e", "a", "a", "a", "a"],
    ...     "train_seed": [-1, -1, 0, 0, 1, 1], "env_seed": [1, 2, 1, 2, 1, 2],
    ...     "reward": [10.0, 20.0, 11.0, 21.0, 13.0, 23.0]})
    >>> paired_to_reference(df, "e", ["reward"])[["method", "d_reward", "n_pairs"]].to_dict(
    ...     "records")
    [{'method': 'a', 'd_reward': 2.0, 'n_pairs': 4}]
    """
    ref = episodes[episodes[by] == reference]
    others = episodes[episodes[by] != reference]
    copies = [ref.assign(**{seeds: s}) for s in sorted(others[seeds].unique())]
    both = pd.concat([others, *copies], ignore_index=True)
    return paired_crossed(both, reference, metrics, by=by, seeds=seeds, **kwargs)  # type: ignore[arg-type]


# --- one-sided bounds: what a sample certifies --------------------------------------------------


def clopper_pearson_upper(k: int, n: int, confidence: float = 0.95) -> float:
    """One-sided Clopper-Pearson upper confidence bound on a share: with ``k`` of ``n``
    independent trials counted, the share is at most this with probability ``confidence``
    (the ``p`` at which ``P(X <= k) = 1 - confidence``; exact, never below the truth's level).

    It is the ``confidence`` quantile of ``Beta(k + 1, n - k)`` (``scipy.stats.beta.ppf``), and
    1 when ``k == n``. Zero of ``n`` bounds the share at ``1 - (1 - confidence)^(1/n)``, about
    ``3 / n`` at 95% (the rule of three).

    >>> round(clopper_pearson_upper(0, 10), 4), round(clopper_pearson_upper(0, 51), 4)
    (0.2589, 0.057)
    >>> round(clopper_pearson_upper(17, 51), 4), clopper_pearson_upper(5, 5)
    (0.4571, 1.0)
    """
    from scipy.stats import beta  # scipy.stats takes ~0.3 s to import; only bounds need it

    if not 0 < confidence < 1:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    if n < 1 or not 0 <= k <= n:
        raise ValueError(f"need 0 <= k <= n and n >= 1, got k={k}, n={n}")
    if k == n:
        return 1.0
    return float(beta.ppf(confidence, k + 1, n - k))


def lower_bound_crossed(
    cells: np.ndarray, confidence: float = 0.95, *, n_boot: int = 2000, seed: int = 0
) -> float:
    """One-sided lower confidence bound on the mean of a crossed ``(training seeds, tracks)``
    table: the ``1 - confidence`` quantile of :func:`crossed_bootstrap_ci`'s replicates (seeds
    and tracks resampled independently), from a generator seeded with ``seed`` (the same
    cells give the same bound). One cell: its value.

    >>> cells = np.array([[700.0, 400.0, 650.0], [690.0, 380.0, 300.0]])
    >>> lb = lower_bound_crossed(cells, 0.9)
    >>> bool(cells.min() <= lb < cells.mean()), lb == lower_bound_crossed(cells, 0.9)
    (True, True)
    """
    if not 0.5 <= confidence < 1:
        raise ValueError(f"confidence must be in [0.5, 1), got {confidence}")
    rng = np.random.default_rng(seed)
    mean, lo, _ = crossed_bootstrap_ci(
        cells, confidence=max(2 * confidence - 1, 1e-9), n_boot=n_boot, rng=rng
    )
    return mean if confidence == 0.5 else lo


def episodes_beyond(episodes: pd.DataFrame) -> np.ndarray:
    """``(N,) bool``: evaluated episodes that reached a state beyond ``d_s``: ``any_violation``
    or, where a table holds it, ``any_violating_session`` (an outcome beyond it).

    >>> frame = pd.DataFrame({"any_violation": [0.0, 0.0, 1.0],
    ...                       "any_violating_session": [1.0, 0.0, 0.0]})
    >>> episodes_beyond(frame).tolist()
    [True, False, True]
    """
    out = episodes["any_violation"].fillna(0).to_numpy(float) > 0
    if "any_violating_session" in episodes:
        out |= episodes["any_violating_session"].fillna(0).to_numpy(float) > 0
    return out


def certified_share(k: int, n: int, confidence: float = 0.95, what: str = "episodes") -> str:
    """The claim ``k`` of ``n`` supports, in words.

    >>> certified_share(0, 51)
    'at most 5.7% of episodes cross d_s (95% one-sided Clopper-Pearson bound; 0 of 51 did)'
    """
    bound = clopper_pearson_upper(k, n, confidence)
    return (
        f"at most {100 * bound:.1f}% of {what} cross d_s ({100 * confidence:g}% one-sided "
        f"Clopper-Pearson bound; {k} of {n} did)"
    )


@dataclass(frozen=True)
class VarianceComponents:
    """Variance of a crossed ``(training seeds, tracks)`` table, one value per cell, split
    into a training-seed part, a track part and the rest (the random-effects two-way model
    ``x[s, t] = mu + a_s + b_t + e_st``, method-of-moments estimates, negatives set to 0)."""

    seed: float
    """Variance of the training-seed effect ``a_s``."""
    track: float
    """Variance of the track effect ``b_t``."""
    residual: float
    """Variance of the seed x track interaction and the episode's own noise ``e_st``."""

    @classmethod
    def of(cls, cells: np.ndarray) -> VarianceComponents:
        """Estimate from a complete ``(S, T)`` table (``S, T >= 2``, no NaN).

        >>> rng = np.random.default_rng(0)
        >>> seed_effect, track_effect = 10 * rng.normal(size=(40, 1)), rng.normal(size=(1, 60))
        >>> x = seed_effect + track_effect + 0.1 * rng.normal(size=(40, 60))
        >>> vc = VarianceComponents.of(x)
        >>> bool(60 < vc.seed < 150 and 0.5 < vc.track < 1.6 and vc.residual < 0.02)
        True
        """
        x = np.asarray(cells, np.float64)
        if x.ndim != 2 or min(x.shape) < 2 or np.isnan(x).any():
            raise ValueError(f"need a complete (seeds >= 2, tracks >= 2) table, got {x.shape}")
        n_s, n_t = x.shape
        grand, rows, cols = x.mean(), x.mean(axis=1), x.mean(axis=0)
        ms_s = n_t * ((rows - grand) ** 2).sum() / (n_s - 1)
        ms_t = n_s * ((cols - grand) ** 2).sum() / (n_t - 1)
        resid = x - rows[:, None] - cols[None, :] + grand
        ms_e = (resid**2).sum() / ((n_s - 1) * (n_t - 1))
        return cls(max((ms_s - ms_e) / n_t, 0.0), max((ms_t - ms_e) / n_s, 0.0), ms_e)

    def half_width(self, seeds: float, tracks: float, z: float = 1.96) -> float:
        """Normal-approximation half-width of the mean of a ``seeds x tracks`` crossed table.

        >>> VarianceComponents(4.0, 0.0, 0.0).half_width(4, 10, z=1.0)
        1.0
        """
        var = self.seed / seeds + self.track / tracks + self.residual / (seeds * tracks)
        return z * math.sqrt(var)


def pareto_mask(reward: np.ndarray, safety: np.ndarray) -> np.ndarray:
    """``(N,) bool``: points no other point beats in both reward and safety (higher is better).

    >>> pareto_mask(np.array([1.0, 2.0, 3.0, 1.0]), np.array([3.0, 2.0, 1.0, 1.0])).tolist()
    [True, True, True, False]
    """
    r, s = np.asarray(reward, float), np.asarray(safety, float)
    ok = np.isfinite(r) & np.isfinite(s)
    out = np.zeros(len(r), bool)
    for i in np.flatnonzero(ok):
        dominated = ok & (r >= r[i]) & (s >= s[i]) & ((r > r[i]) | (s > s[i]))
        out[i] = not dominated.any()
    return out
