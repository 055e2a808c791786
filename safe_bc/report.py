"""Cells of the Markdown result tables: one format for an estimate and its interval."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import pandas as pd

__all__ = ["fmt_ci", "markdown_table"]


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
