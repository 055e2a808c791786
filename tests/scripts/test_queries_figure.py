"""The figure of the queries family's committed summaries (``scripts/queries_figure.py``)."""

from __future__ import annotations

from pathlib import Path

import pytest


def test_the_figure_reads_the_committed_measurements(tmp_path) -> None:
    """``python -m scripts.queries_figure`` draws the committed summaries; the deferred share
    it labels is the mean ``deferred_share`` of the chosen deferral's fresh episodes."""
    import pandas as pd

    from scripts.queries_figure import deferred_shares, main

    root = Path(__file__).resolve().parents[2] / "results/queries"
    assert main([str(tmp_path / "q.png"), str(root / "carracing"), str(root / "rehab")]) == 0
    assert (tmp_path / "q.png").stat().st_size > 10_000
    summary = pd.read_parquet(root / "rehab/summary.parquet")
    shares = deferred_shares(root / "rehab", summary)
    episodes = pd.read_parquet(root / "rehab/queries_episodes.parquet")
    assert shares["defer"] == pytest.approx(
        episodes.loc[episodes["method"] == "defer-0.2", "deferred_share"].mean()
    )
    assert set(shares) == {"defer", "critical+defer"}
    assert main([]) == 2
