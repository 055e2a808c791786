"""Evaluation metrics and confidence intervals (pure numpy/pandas: no I/O, no Ray)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from safe_bc.episode import Episode


def combined(safety: np.ndarray) -> np.ndarray:
    """One safety number per step: the smallest distance of the dimensions.

    Args:
        safety: ``(T, S)`` distances (higher is safer).

    Returns:
        ``(T,) float32``.
    """
    return np.min(safety, axis=-1).astype(np.float32)


def critical_zone(costs: np.ndarray, thresholds: np.ndarray, eps: float) -> np.ndarray:
    """``(T,) bool``: steps with some cost at or beyond ``threshold - eps`` (the T_eps rule)."""
    return np.any(costs >= np.asarray(thresholds) - eps, axis=-1)


def episode_metrics(
    episode: Episode,
    *,
    tiles_visited: float = float("nan"),
    thresholds: np.ndarray | None = None,
    eps: float = 5.0,
) -> dict[str, float]:
    """Reward and safety of one evaluated episode.

    Safety statistics use the scored steps only (the CarRacing zoom-in is
    excluded). ``critical_share`` is the share of scored steps inside the critical
    zone defined by the demonstrations' ``thresholds`` and ``eps``; ``offroad_steps``
    counts the unsafe events (all wheels on grass / a safety limit crossed).

    >>> import numpy as np
    >>> T = 5
    >>> ep = Episode(0, 1, np.zeros((T, 0)), np.zeros((T, 3)), np.zeros((T, 3)),
    ...     np.full(T, 2.0), np.zeros(T, bool), np.zeros(T, bool),
    ...     np.array([[5, 60, 5], [4, 60, 6], [3, 60, 7], [2, 60, 8], [1, 60, 9.]]),
    ...     np.zeros((T, 3)), np.array([1, 0, 0, 0, 0], bool), np.zeros(T, bool))
    >>> m = episode_metrics(ep)
    >>> m["reward"], m["steps"], m["safety_min"], m["safety_left_mean"]
    (10.0, 5, 1.0, 2.5)
    """
    scored = ~episode.warmup
    if not scored.any():
        scored = np.ones(len(episode), bool)
    safety = episode.safety[scored]
    comb = combined(safety)
    out: dict[str, float] = {
        "reward": episode.total_reward,
        "steps": len(episode),
        "tiles_visited": float(tiles_visited),
        "safety_mean": float(comb.mean()),
        "safety_std": float(comb.std()),
        "safety_min": float(comb.min()),
        "offroad_steps": int(episode.offroad[scored].sum()),
        "terminated": bool(episode.terminated[-1]),
    }
    for j, d in enumerate(episode.safety_dims):
        out[f"safety_{d}_mean"] = float(safety[:, j].mean())
        out[f"safety_{d}_std"] = float(safety[:, j].std())
        out[f"safety_{d}_min"] = float(safety[:, j].min())
    if thresholds is not None:
        out["critical_share"] = float(critical_zone(episode.costs[scored], thresholds, eps).mean())
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
    if groups is None:
        groups = np.arange(len(values))
    labels = np.unique(groups)
    members = [values[groups == g] for g in labels]
    boots = np.empty(n_boot)
    for b in range(n_boot):
        picked = rng.integers(0, len(members), len(members))
        parts = [members[i][rng.integers(0, len(members[i]), len(members[i]))] for i in picked]
        boots[b] = np.concatenate(parts).mean()
    tail = (1 - confidence) / 2
    lo, hi = np.quantile(boots, [tail, 1 - tail])
    return mean, float(lo), float(hi)


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

    Pairing removes the spread between tracks, which dominates single-method CIs.
    Methods without a matching pair (e.g. the expert, trained once) are left out.

    >>> df = pd.DataFrame({"method": ["a", "a", "b", "b"], "train_seed": [0, 0, 0, 0],
    ...                    "env_seed": [1, 2, 1, 2], "reward": [10.0, 20.0, 12.0, 23.0]})
    >>> paired_differences(df, "a", ["reward"])[["method", "d_reward"]].to_dict("records")
    [{'method': 'b', 'd_reward': 2.5}]
    """
    rng = np.random.default_rng(seed)
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
            mean, lo, hi = bootstrap_ci(
                diff[m].to_numpy(float), groups, confidence=confidence, rng=rng
            )
            row[f"d_{m}"], row[f"d_{m}_lo"], row[f"d_{m}_hi"] = mean, lo, hi
        rows.append(row)
    return pd.DataFrame(rows)
