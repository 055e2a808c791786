"""The queries family's summary (``scripts/queries_report.py``) re-derived from the committed
comparison outputs."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[2]
FAMILY = ROOT / "tune_jobs/compare/queries.py"


@pytest.mark.parametrize(
    ("task", "not_kept"), [("rehab", ()), ("carracing", ("queries_per_episode",))]
)
def test_the_committed_summary_re_derives_from_the_comparisons(
    task: str, not_kept: tuple[str, ...], monkeypatch
) -> None:
    """The committed summary and widths table are those of the family's two committed
    comparisons (their episode tables and the selection's query history), value for value.
    The car's query runs were not kept (its episodes were adopted as stored evaluations, its
    agents not retrained), so its queries per episode, counted in those runs, are not
    re-derived; every other value is."""
    from safe_bc.compare.families import load_comparison
    from safe_bc.data.store import read_table
    from scripts.queries_report import summary

    monkeypatch.chdir(ROOT)
    selection = load_comparison(FAMILY, f"{task}_selection")
    fresh = load_comparison(FAMILY, task)
    table, widths = summary(selection, fresh)
    folder = ROOT / "results/queries" / task
    committed = read_table(folder / "summary.parquet")[0]
    assert list(table.columns) == list(committed.columns) and len(table) == 14
    pd.testing.assert_frame_equal(
        table.drop(columns=list(not_kept)), committed.drop(columns=list(not_kept)), check_exact=True
    )
    pd.testing.assert_frame_equal(
        widths, read_table(folder / "widths.parquet")[0], check_exact=True
    )
