"""Cells of the Markdown result tables: one format for an estimate and its interval."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import pandas as pd

__all__ = ["MIN_EPISODES_FOR_INTERVAL", "estimate_lines", "fmt_ci", "markdown_table"]


MIN_EPISODES_FOR_INTERVAL = 5
"""Fewest episodes whose mean is printed with a 95% interval. A percentile bootstrap interval
never leaves the sample's range ``[min, max]``, and ``n`` episodes' range holds even the
median of a continuous distribution with probability ``1 - 2 ** (1 - n)`` only: 50% for 2
episodes, 87.5% for 4, 94% for 5. Below 5 a "95% CI" would claim more than it can hold, so
the means are printed alone."""


def estimate_lines(row: Mapping[str, Any], metrics: Sequence[str], n_episodes: int) -> list[str]:
    """One line per metric of a summary row: ``<metric>: mean  95% CI [lo, hi]``, or, from
    fewer than :data:`MIN_EPISODES_FOR_INTERVAL` episodes, the means alone after a line that
    says why.

    >>> row = {"reward": 2.0, "reward_lo": 1.0, "reward_hi": 3.0}
    >>> for line in estimate_lines(row, ["reward"], 10):
    ...     print(line)
             reward:     2.000  95% CI [1.000, 3.000]
    >>> for line in estimate_lines(row, ["reward"], 2):
    ...     print(line)
    means of 2 episodes (too few episodes for an interval: fewer than 5)
             reward:     2.000
    """
    if n_episodes < MIN_EPISODES_FOR_INTERVAL:
        head = (
            f"means of {n_episodes} episode{'s' if n_episodes != 1 else ''} (too few episodes "
            f"for an interval: fewer than {MIN_EPISODES_FOR_INTERVAL})"
        )
        return [head, *(f"{m:>15}: {row[m]:9.3f}" for m in metrics)]
    return [
        f"{m:>15}: {row[m]:9.3f}  95% CI [{row[m + '_lo']:.3f}, {row[m + '_hi']:.3f}]"
        for m in metrics
    ]


def markdown_table(rows: Sequence[Sequence[object]], columns: Sequence[str]) -> str:
    """A Markdown (pipe) table of cells already formatted as text: ``DataFrame.to_markdown``
    (tabulate), with number parsing off so that every cell reads as written.

    >>> print(markdown_table([["a", "0.50"], ["b", "904 [891, 913]"]], ["method", "reward"]))
    | method   | reward         |
    |:---------|:---------------|
    | a        | 0.50           |
    | b        | 904 [891, 913] |
    """
    frame = pd.DataFrame([[str(c) for c in r] for r in rows], columns=list(columns))
    return frame.to_markdown(index=False, disable_numparse=True)


def fmt_ci(
    row: Mapping[str, Any],
    metric: str,
    digits: int = 1,
    *,
    signed: bool = False,
    blank_missing: bool = False,
) -> str:
    """``mean [lo, hi]`` of ``metric`` in a summary or paired row (keys ``metric``,
    ``metric_lo``, ``metric_hi``), each with ``digits`` decimals.

    Args:
        signed: write every number with its sign (``+d [+lo, +hi]``), for differences.
        blank_missing: ``""`` when the row has no finite ``metric`` (else that raises or
            prints ``nan``).

    >>> fmt_ci({"reward": 904.2, "reward_lo": 891.0, "reward_hi": 913.4}, "reward", 0)
    '904 [891, 913]'
    >>> fmt_ci({"d": -4.04, "d_lo": -9.2, "d_hi": 0.5}, "d", signed=True)
    '-4.0 [-9.2, +0.5]'
    >>> fmt_ci({"d": float("nan")}, "d", blank_missing=True)
    ''
    """
    value = row.get(metric)
    if blank_missing and (value is None or not math.isfinite(float(value))):
        return ""
    spec = f"{'+' if signed else ''}.{digits}f"
    lo, hi = row[f"{metric}_lo"], row[f"{metric}_hi"]
    return f"{value:{spec}} [{lo:{spec}}, {hi:{spec}}]"


DISTANCE_UNIT = "the task's distance to its limit (CarRacing: px to the grass)"
"""Unit of safety distances and their differences, named without a task."""

_UNITS: tuple[tuple[str, str], ...] = (
    ("seconds", "s"),
    ("_s", "s"),
    ("minutes", "min"),
    ("share", "fraction of 1"),
    ("fraction", "fraction of 1"),
    ("_rate", "fraction of 1"),
    ("_ucb", "fraction of 1 (one-sided 95% upper bound)"),
    ("ucb95", "fraction of 1 (one-sided 95% upper bound)"),
    ("reward", "return (the env's reward summed over an episode)"),
    ("safety", DISTANCE_UNIT),
    ("excursion", DISTANCE_UNIT),
    ("steps", "env steps"),
    ("episodes", "episodes"),
    ("samples_per_s", "samples / s"),
    ("loss", "mean squared action error"),
)
"""``(part of a column name, unit)``, first match wins (see :func:`column_unit`)."""


def column_unit(name: str) -> str | None:
    """The unit of a result table's column, read off its name (``None``: a label, a count
    without unit, a setting).

    >>> column_unit("reward_lo")
    "return (the env's reward summed over an episode)"
    >>> column_unit("safety_min") == DISTANCE_UNIT, column_unit("deferred_share")
    (True, 'fraction of 1')
    >>> column_unit("duration_s"), column_unit("episodes_beyond"), column_unit("method")
    ('s', 'episodes', None)
    """
    if name == "samples_per_s":
        return "samples / s"
    for part, unit in _UNITS:
        if part == "_s" and not name.endswith("_s"):
            continue
        if part in name:
            return unit
    return None


def units_of(names: Sequence[str]) -> dict[str, str]:
    """Column name -> its unit (:func:`column_unit`), for the columns whose name tells one.

    >>> units_of(["reward_lo", "method"])
    {'reward_lo': "return (the env's reward summed over an episode)"}
    """
    return {n: u for n in names if (u := column_unit(n)) is not None}
