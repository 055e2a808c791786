"""The figure of the query and deferral measurements (:mod:`safe_bc.queries.measure`):
``python -m safe_bc.queries.figure OUT DIR [DIR ...]``
draws every ``DIR`` (a ``safe_bc.queries.measure`` output folder: its ``summary.parquet`` and
its committed episode tables) as one testbed row of :func:`safe_bc.plots.plot_queries`, on the
fresh tracks (patients), into ``OUT`` (PNG)."""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd


def deferred_shares(folder: Path, block: int) -> dict[str, float]:
    """Mean share of steps deferred to the expert per deferring method, over its episodes of
    held-out ``block`` (the episode tables' ``deferred_share``)."""
    from safe_bc.data.store import read_table

    frames = [read_table(p)[0] for p in sorted((folder / "episodes" / f"block{block}").glob("*"))]
    episodes = pd.concat(frames, ignore_index=True)
    if "deferred_share" not in episodes:
        return {}
    shares = episodes.dropna(subset=["deferred_share"]).groupby("method")["deferred_share"]
    return {str(k): float(v) for k, v in shares.mean().items()}


def draw(out: Path, folders: list[Path]) -> Path:
    """The figure of ``folders`` (one row each, named by the measured task) at ``out``."""
    from safe_bc.data.store import read_table
    from safe_bc.plots import plot_queries
    from safe_bc.queries.measure import FRESH_BLOCK

    summaries, deferred = {}, {}
    for folder in folders:
        table, meta = read_table(folder / "summary.parquet")
        name = str(meta.get("task", "carracing"))  # (the first CarRacing run predates the field)
        summaries[name] = table
        deferred[name] = deferred_shares(folder, FRESH_BLOCK)
    return plot_queries(summaries, deferred, out)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) < 2:
        print("usage: python -m safe_bc.queries.figure OUT.png DIR [DIR ...]", file=sys.stderr)
        return 2
    print(draw(Path(args[0]), [Path(a) for a in args[1:]]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
