"""The figure of the query and deferral measurements (the queries family,
``tune_jobs/compare/queries.py``): ``python -m scripts.queries_figure OUT DIR [DIR ...]``
draws every ``DIR`` (a task's folder: its ``summary.parquet`` and its fresh comparison's
episode table, ``queries_episodes.parquet``) as one testbed row of
:func:`safe_bc.plots.plot_queries`, on the fresh tracks (patients), into ``OUT`` (PNG)."""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd

FRESH = "queries"
"""The fresh comparison's name (its episode table ``<name>_episodes.parquet``)."""


def deferred_shares(folder: Path, summary: pd.DataFrame) -> dict[str, float]:
    """Mean share of steps deferred to the expert per deferring method of the ``summary`` (its
    fresh rows with a width), over that deferral's episodes on the fresh tracks (the row
    ``<method>-<width>`` of the fresh comparison's episode table)."""
    from safe_bc.data.store import read_table

    episodes = read_table(folder / f"{FRESH}_episodes.parquet")[0]
    fresh = summary[(summary["block"] == "fresh") & summary["width"].notna()]
    return {
        str(m): float(episodes.loc[episodes["method"] == f"{m}-{w:g}", "deferred_share"].mean())
        for m, w in zip(fresh["method"], fresh["width"], strict=True)
    }


def draw(out: Path, folders: list[Path]) -> Path:
    """The figure of ``folders`` (one row each, named by the measured task) at ``out``."""
    from safe_bc.data.store import read_table
    from safe_bc.plots import plot_queries

    summaries, deferred = {}, {}
    for folder in folders:
        table, meta = read_table(folder / "summary.parquet")
        name = str(meta.get("task", "carracing"))  # (the first CarRacing run predates the field)
        summaries[name] = table
        deferred[name] = deferred_shares(folder, table)
    return plot_queries(summaries, deferred, out)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) < 2:
        print("usage: python -m scripts.queries_figure OUT.png DIR [DIR ...]", file=sys.stderr)
        return 2
    print(draw(Path(args[0]), [Path(a) for a in args[1:]]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
