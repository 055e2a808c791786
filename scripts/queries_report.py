"""Write the queries family's summary from its comparisons' outputs.

``python -m scripts.queries_report tune_jobs/compare/queries.py --name rehab``: the fresh
comparison ``rehab`` and the selection comparison it follows (both run by ``safe-bc compare``
first) give ``OUT/summary.parquet``, ``summary.md`` and ``widths.parquet``
(:mod:`safe_bc.methods.queries.summary`). Nothing is trained or evaluated.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import pandas as pd

from safe_bc.compare.families import family, load_comparison
from safe_bc.compare.protocol import Fresh, candidates
from safe_bc.compare.rows import Handover
from safe_bc.compare.spec import Comparison
from safe_bc.data.atomic import write_text_atomic
from safe_bc.data.provenance import run_metadata
from safe_bc.data.store import read_table, write_table_atomic
from safe_bc.methods.queries.summary import (
    CROSSING,
    DEFERRAL,
    block_episodes,
    queries_per_episode,
    summarize,
    widths_table,
)

NO_HISTORY = pd.DataFrame(columns=["method", "train_seed", "queries", "episodes"])
"""A query history without runs."""


def deferrals(comparison: Comparison) -> list[Handover]:
    """The comparison's deferral rows (handovers with a width)."""
    return candidates(comparison)


def summary(selection: Comparison, fresh: Comparison) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The summary and the widths table of a selection comparison and its fresh one, from
    their stored episode tables and the selection's query history (absent where the query
    runs were not kept: no queries per episode then, NaN)."""
    crossing = CROSSING[selection.task]
    sel = read_table(selection.out / f"{selection.name}_episodes.parquet")[0]
    new = read_table(fresh.out / f"{fresh.name}_episodes.parquet")[0]
    runs = selection.out / f"{selection.name}_history.parquet"
    history = read_table(runs)[0] if runs.is_file() else NO_HISTORY
    picked = deferrals(fresh)
    chosen = {r.name: DEFERRAL[r.of] for r in picked}
    widths = {DEFERRAL[r.of]: float(r.handover.width) for r in picked}  # type: ignore[union-attr]
    episodes = pd.concat(
        [
            block_episodes(sel, chosen, selection.eval_seed),
            block_episodes(new, chosen, fresh.eval_seed),
        ],
        ignore_index=True,
    )
    tried = [(r.name, r.of, float(r.handover.width)) for r in deferrals(selection)]  # type: ignore[union-attr]
    table = summarize(episodes, queries_per_episode(history), widths, crossing, selection.eval_seed)
    return table, widths_table(sel, tried, crossing)


def markdown(selection: Comparison, fresh: Comparison, table: pd.DataFrame, meta: dict) -> str:
    """The summary as Markdown: the design in a paragraph, the table, the provenance."""
    widths = {DEFERRAL[r.of]: r.handover.width for r in deferrals(fresh)}  # type: ignore[union-attr]
    text = (
        f"# {fresh.title or fresh.name}: summary\n\nTraining seeds {selection.train_seeds}, "
        f"{selection.episodes} episodes per seed and block (selection: held-out block "
        f"{selection.eval_seed}; fresh: {fresh.eval_seed}). Deferral widths chosen on the "
        f"selection block: {widths}. An episode is beyond d_s when its "
        f"`{CROSSING[selection.task]}` is above 0; critical+defer's queries are its agent's "
        "training queries.\n\n"
    )
    return (
        text
        + table.to_markdown(index=False, floatfmt=".3g")
        + f"\n\nProvenance: code {meta['git_revision']}, command `{meta['command']}`.\n"
    )


def write(path: str | Path, name: str) -> pd.DataFrame:
    """Write the summary of family ``path``'s fresh comparison ``name`` into its folder."""
    entry = family(path)[name]
    if not isinstance(entry, Fresh):
        raise ValueError(f"{path}: {name!r} is no fresh comparison (it follows none)")
    selection, fresh = load_comparison(path, entry.follows), load_comparison(path, name)
    table, widths = summary(selection, fresh)
    meta: dict[str, Any] = run_metadata(
        task=selection.task, selection=selection.name, fresh=fresh.name,
        crossing=CROSSING[selection.task],
    )  # fmt: skip
    write_table_atomic(fresh.out / "summary.parquet", table, meta)
    write_table_atomic(fresh.out / "widths.parquet", widths, meta)
    write_text_atomic(fresh.out / "summary.md", markdown(selection, fresh, table, meta))
    return table


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("file", help="the family file (tune_jobs/compare/queries.py)")
    parser.add_argument("--name", required=True, help="its fresh comparison (e.g. rehab)")
    a = parser.parse_args(argv)
    try:
        print(write(a.file, a.name).to_markdown(index=False, floatfmt=".3g"))
    except (FileNotFoundError, KeyError, ValueError) as e:
        parser.exit(2, f"error: {e}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
