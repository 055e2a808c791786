"""Adopt the CarRacing queries measurement's committed episode files as the stored evaluations
of the queries family's CarRacing comparisons, and write the comparisons' tables from them.

``python scripts/adopt_queries_episodes.py`` (from the repository root, a clean tree): each
file ``results/queries/carracing/episodes/block<b>/<method>-<seed>.parquet`` (made one env at
a time, as ``lockstep_forward="rows"`` evaluates) becomes the stored evaluation of the cell
that made it, ``stored_evaluations/<key>.parquet`` keyed by the cell's stamp (thresholds: the
limits the measurement recorded), its rows and values unchanged (a ``policy`` column in place
of ``method``, ``train_seed``, ``block``; the metadata keeps the original and adds the stamp).
Then the selection comparison's tables (episodes, an empty training table: its agents and
query rounds were not committed, so no training or query columns) and those of the fresh
comparison, whose rows the rule picks on the selection table just written. Nothing is
trained or evaluated; a CarRacing rerun (about 20 minutes on 16 cores) would remake them.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd

from safe_bc.compare import Comparison, Expert
from safe_bc.compare_rows import Handover
from safe_bc.data.store import read_table, read_table_metadata, write_table_atomic
from safe_bc.distributed.compare import plan_evaluations, write_outputs
from safe_bc.eval_store import episodes_path
from safe_bc.families import load_comparison
from safe_bc.provenance import run_metadata

FAMILY = Path("tune_jobs/compare/queries.py")
FOLDER = Path("results/queries/carracing")
MEASURED = ("method", "train_seed", "block")
"""The measurement's labelling columns (the stored evaluation names its policy instead)."""


def measured_file(row, seed: int, block: int, chosen: bool) -> Path:
    """The measurement's episode file of a cell: ``expert--1``, ``<row>-<seed>``; a chosen
    deferral on the fresh block ``<defer|critical+defer>-<seed>``."""
    if isinstance(row, Expert):
        return FOLDER / "episodes" / f"block{block}" / "expert--1.parquet"
    name = row.name
    if chosen and isinstance(row, Handover):
        name = name.rsplit("-", 1)[0]
    return FOLDER / "episodes" / f"block{block}" / f"{name}-{seed}.parquet"


def adopt(c: Comparison, limits: list[float], fresh: bool) -> None:
    """Store every cell's measured episodes under its stamp's key, then write the tables."""
    plan = plan_evaluations(c, {c.demos: limits})
    stored = {}
    for key, cell in plan.items():
        source = measured_file(cell.row, cell.seed, c.eval_seed, fresh)
        frame, meta = read_table(source)
        ep = frame.drop(columns=list(MEASURED))
        ep.insert(0, "policy", key)
        write_table_atomic(episodes_path(c.out, cell.stamp), ep, {**meta, "stamp": cell.stamp})
        stored[key] = ep
    from safe_bc.distributed.compare import episodes_table

    episodes = episodes_table(plan, stored)
    meta = run_metadata(config=c.to_dict(), train_seeds=list(c.train_seeds), eval_seed=c.eval_seed)
    meta["adopted_from"] = str(FOLDER / "episodes" / f"block{c.eval_seed}")
    empty = pd.DataFrame()
    write_table_atomic(c.out / f"{c.name}_episodes.parquet", episodes, meta)
    write_table_atomic(c.out / f"{c.name}_traces.parquet", empty, meta)
    write_table_atomic(c.out / f"{c.name}_training.parquet", empty, meta)
    write_outputs(c, episodes, empty, empty, meta)


def main() -> int:
    limits = read_table_metadata(FOLDER / "summary.parquet")["limits"]
    adopt(load_comparison(FAMILY, "carracing_selection"), limits, fresh=False)
    adopt(load_comparison(FAMILY, "carracing"), limits, fresh=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
