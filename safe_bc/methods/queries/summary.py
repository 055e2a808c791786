"""The queries family's summary (``tune_jobs/compare/queries.py``): per block (selection,
fresh) and method, the episodes beyond d_s with their one-sided 95% Clopper-Pearson bound,
reward and its paired crossed-bootstrap difference to the expert, queries or deferred steps
per episode, the deferral widths; and the widths tried on the selection tracks.

Pure (pandas): the caller reads the comparisons' episode and history tables
(``scripts/queries_report.py``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import pandas as pd

from safe_bc.metrics import clopper_pearson_upper, paired_to_reference

EXPERT = "expert"
DEFERRAL = {"bc": "defer", "critical": "critical+defer"}
"""The agent a deferral hands over -> the summary's name of the deferral."""
ORDER = (("expert",), ("bc", "defer"), ("bc_safe",), ("full", "critical"), ("critical+defer",))
"""The summary's methods in the order its episodes are laid out per block: the expert, then
per training seed each group's methods (the order their pairs are resampled in)."""
CROSSING = {"carracing": "violation_steps", "rehab": "violating_sessions"}
"""Per task, the per-episode count whose being above 0 makes an episode *beyond d_s*: a scored
step (the car), a session's outcome, the last one included (the clinic, whose
``violation_steps`` scores the state before each session and misses the last outcome)."""
QUERY_METHODS = ("bc", "full", "critical")
"""The methods whose queries per episode the summary reports (plain BC: none asked, NaN)."""


def block_episodes(episodes: pd.DataFrame, chosen: Mapping[str, str], block: int) -> pd.DataFrame:
    """One block's episodes for the summary from a comparison's episode table (``method``,
    ``train_seed`` and the metrics, one cell after another): the deferral rows ``chosen``
    (row name -> summary name, e.g. ``{"defer-0.2": "defer"}``) renamed, other deferral rows
    dropped, laid out in :data:`ORDER` with ``block`` set."""
    named = episodes.assign(method=episodes["method"].replace(dict(chosen)))
    named = named[named["method"].isin({m for group in ORDER for m in group})]
    seeds = sorted(named.loc[named["method"] != EXPERT, "train_seed"].unique())
    parts = [named[named["method"] == EXPERT]]
    for group in ORDER[1:]:
        for s in seeds:
            for m in group:
                parts.append(named[(named["method"] == m) & (named["train_seed"] == s)])
    keep = [c for c in named.columns if c not in ("policy", "mode", "alpha", "rest")]
    return pd.concat(parts, ignore_index=True)[keep].assign(block=block)


def queries_per_episode(history: pd.DataFrame) -> dict[str, float]:
    """Per query method, its queries per rollout episode (each run's total over its
    episodes, mean over training seeds); ``critical+defer`` its agent's, ``bc_safe`` 0."""
    runs = history.groupby(["method", "train_seed"])[["queries", "episodes"]].sum()
    per_run = runs["queries"] / runs["episodes"]
    out = {m: float(per_run.loc[m].mean()) if m in per_run else float("nan") for m in QUERY_METHODS}
    out["critical+defer"], out["bc_safe"] = out["critical"], 0.0
    return out


def widths_table(
    episodes: pd.DataFrame, rows: Sequence[tuple[str, str, float]], crossing: str
) -> pd.DataFrame:
    """The widths tried on the selection tracks: per deferral row ``(row, agent, width)`` the
    episodes beyond d_s (``crossing`` above 0) of all its training seeds, smallest width first
    per agent."""
    out = []
    for name, agent, width in sorted(rows, key=lambda r: (list(DEFERRAL).index(r[1]), r[2])):
        m = episodes[episodes["method"] == name]
        out.append(
            {
                "agent": agent,
                "width": width,
                "episodes_beyond": int((m[crossing] > 0).sum()),
                "episodes": len(m),
            }
        )
    return pd.DataFrame(out)


def summarize(
    episodes: pd.DataFrame,
    queries: dict[str, float],
    widths: dict[str, float],
    crossing: str = "violation_steps",
    selection_block: int = 11,
) -> pd.DataFrame:
    """Per (block, method): episodes beyond d_s (``crossing`` above 0), their 95% upper bound,
    reward and its paired difference to the expert (crossed bootstrap), queries / deferred
    steps per episode, the width of a deferral."""
    rows = []
    for block, df in episodes.groupby("block", sort=True):
        paired = paired_to_reference(df, EXPERT, ["reward"]).set_index("method")
        for method, m in df.groupby("method", sort=False):
            k, n = int((m[crossing] > 0).sum()), len(m)
            row: dict[str, Any] = {
                "block": "selection" if block == selection_block else "fresh",
                "method": method,
                "episodes": n,
                "episodes_beyond": k,
                "beyond_ucb95": clopper_pearson_upper(k, n),
                "reward": float(m["reward"].mean()),
            }
            if method in paired.index:
                for c in ("d_reward", "d_reward_lo", "d_reward_hi"):
                    row[f"{c}_vs_expert"] = float(paired.loc[method, c])
            row["queries_per_episode"] = queries.get(method, float("nan"))
            deferred = m.get("deferred_steps")
            row["deferred_steps_per_episode"] = (
                float(deferred.mean())
                if deferred is not None and deferred.notna().any()
                else float("nan")
            )
            row["width"] = widths.get(method, float("nan"))
            rows.append(row)
    return pd.DataFrame(rows)
