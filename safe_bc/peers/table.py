"""The peers' table: per row, reward with a crossed CI, its paired difference to the expert
(the guideline), and the episodes beyond ``d_s``. Pure: frames in, frames and text out."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd

from safe_bc.metrics import (
    clopper_pearson_upper,
    episodes_beyond,
    paired_to_reference,
    summarize_crossed,
)

SEP = " | seed="
"""How a policy's key names its row and training seed (``<row> | seed=<k>``)."""


def policy_key(row: str, seed: int | None) -> str:
    """The evaluation's key of ``row``'s agent of training seed ``seed`` (``None``: a row
    evaluated once, the expert).

    >>> policy_key("CPQ", 2), policy_key("guideline", None)
    ('CPQ | seed=2', 'guideline')
    """
    return row if seed is None else f"{row}{SEP}{seed}"


def split_policies(episodes: pd.DataFrame) -> pd.DataFrame:
    """``episodes`` (a ``policy`` column of :func:`policy_key` keys) with ``method`` and
    ``train_seed`` (-1 for a row evaluated once) and ``beyond`` (1.0 where the episode reached
    a state beyond ``d_s``, :func:`safe_bc.metrics.episodes_beyond`).

    >>> df = pd.DataFrame({"policy": ["a | seed=1", "e"], "any_violation": [1.0, 0.0]})
    >>> split_policies(df)[["method", "train_seed", "beyond"]].values.tolist()
    [['a', 1, 1.0], ['e', -1, 0.0]]
    """
    parts = episodes["policy"].str.split(SEP, n=1, regex=False)
    out = episodes.copy()
    out["method"] = parts.str[0]
    out["train_seed"] = [int(p[1]) if len(p) > 1 else -1 for p in parts]
    out["beyond"] = episodes_beyond(episodes).astype(float)
    return out


def peers_table(
    episodes: pd.DataFrame,
    reference: str,
    rows: Mapping[str, Mapping[str, Any]],
    *,
    seed: int = 0,
) -> pd.DataFrame:
    """One row per method of ``rows`` (in its order; values: the row's own columns, e.g.
    ``source`` and ``budget``): ``reward`` with its crossed CI over training seeds x patients,
    ``d_reward`` to ``reference`` (paired on the patients, :func:`paired_to_reference`),
    ``beyond`` (episodes beyond ``d_s``) of ``n_episodes`` with its 95% one-sided upper bound
    ``beyond_upper``, ``safety_mean`` and, where a row hands over, ``deferred_share``.
    ``episodes``: :func:`split_policies`'s frame."""
    metrics = [m for m in ("reward", "safety_mean", "deferred_share") if m in episodes]
    summary = summarize_crossed(episodes, ["method"], metrics, seed=seed).set_index("method")
    paired = paired_to_reference(episodes, reference, ["reward"], seed=seed).set_index("method")
    counts = episodes.groupby("method")["beyond"].sum()
    out = []
    for name, own in rows.items():
        if name not in summary.index:
            raise ValueError(f"row {name!r} has no episodes")
        s = summary.loc[name]
        k, n = int(counts[name]), int(s["n_episodes"])
        row: dict[str, Any] = {"method": name, **own}
        row.update({"train_seeds": int(s["n_train_seeds"]), "patients": int(s["n_tracks"]),
                    "n_episodes": n, "reward": s["reward"], "reward_lo": s["reward_lo"],
                    "reward_hi": s["reward_hi"]})  # fmt: skip
        for c in ("d_reward", "d_reward_lo", "d_reward_hi"):
            row[c] = float(paired.loc[name, c]) if name in paired.index else float("nan")
        row["beyond"] = k
        row["beyond_upper"] = clopper_pearson_upper(k, n)
        for m in metrics[1:]:
            row[m] = float(s[m])
        out.append(row)
    return pd.DataFrame(out)


def _ci(x: float, lo: float, hi: float, signed: bool = False) -> str:
    if not np.isfinite(x):
        return ""
    f = "{:+.2f}" if signed else "{:.2f}"
    return f"{f.format(x)} [{f.format(lo)}, {f.format(hi)}]"


def markdown_table(table: pd.DataFrame, reference: str) -> list[str]:
    """The table as Markdown lines."""
    lines = [
        f"| row | source | budget | seeds x patients | reward | vs {reference} (paired) "
        "| beyond d_s | at most (95%) | safety mean | handed over |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for _, r in table.iterrows():
        deferred = r.get("deferred_share", float("nan"))
        lines.append(
            f"| {r['method']} | {r.get('source', '')} | {r.get('budget', '')} "
            f"| {r['train_seeds']} x {r['patients']} "
            f"| {_ci(r['reward'], r['reward_lo'], r['reward_hi'])} "
            f"| {_ci(r['d_reward'], r['d_reward_lo'], r['d_reward_hi'], True) or '(reference)'} "
            f"| {r['beyond']} of {r['n_episodes']} | {100 * r['beyond_upper']:.1f}% "
            f"| {r['safety_mean']:.3f} "
            f"| {'' if not np.isfinite(deferred) else f'{100 * deferred:.1f}%'} |"
        )
    return lines


__all__ = ["SEP", "markdown_table", "peers_table", "policy_key", "split_policies"]
