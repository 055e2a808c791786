"""The cluster analyses' pure parts: the batch-size replay on the committed default study
(``scripts.cluster_schedule``) and the scaling table (``scripts.cluster_scaling``)."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from scripts import cluster_scaling, cluster_schedule

REPO = Path(__file__).resolve().parents[2]


def test_halving_replay_and_tpe_counts() -> None:
    scores = np.array([5.0, 1.0, 3.0, 0.0, 9.0, np.nan])
    assert cluster_schedule.replay_stops(scores, 2).tolist() == [False, False, False, True,
                                                                 False, False]  # fmt: skip
    assert not cluster_schedule.replay_stops(scores, 6).any()  # one batch: never stopped
    assert cluster_schedule.tpe_counts(16, 2, 6) == (10, 10.0)
    assert cluster_schedule.tpe_counts(16, 8, 6) == (8, 8.0)
    assert cluster_schedule.tpe_counts(16, 16, 6) == (0, 0.0)


def test_the_replay_of_the_committed_default_study_gives_its_stops() -> None:
    table = cluster_schedule.replay(REPO / "results" / "default_two_seeds", "default")
    assert table["batch_size"].tolist() == list(cluster_schedule.BATCHES)
    first = table.iloc[0]
    assert first["cost_2_slots_vs_batch_2"] == 0 and first["speedup_16_vs_2"] == 1
    assert (table["wall_s_16_slots"] <= table["wall_s_2_slots"]).all()
    assert table["stopped"].iloc[-1] == 0  # one batch of 16: the halving never stops


def test_the_scaling_study_and_table(tmp_path: Path) -> None:
    args = argparse.Namespace(study=REPO / "tune_jobs" / "default.py", cpus=16, batch_size=None,
                              max_concurrent=None, trials=4, batches=None, demos=None)  # fmt: skip
    spec = cluster_scaling.study_for(args, tmp_path)
    assert (spec.batch_size, spec.max_concurrent, spec.trials) == (16, None, 4)
    assert spec.concurrency(16) == 4 and spec.results == tmp_path / "results"
    row = dict.fromkeys(cluster_scaling.COLUMNS, "")
    out = tmp_path / "scaling.parquet"
    two = {**row, "cpus": 2, "trials_per_min": 1.0, "tuning_seconds": 240.0,
           "trial_seconds_mean": 100.0}  # fmt: skip
    cluster_scaling.append_row(out, two)
    table = cluster_scaling.append_row(out, {**two, "cpus": 16, "trials_per_min": 6.5})
    assert table["cpus"].tolist() == [2, 16]
    md = cluster_scaling.report(table)
    assert "| 6.50 " in md and "6.50x" in md and "1.00x" in md
    assert cluster_scaling.main(["--report", str(out)]) == 0
    assert out.with_suffix(".md").read_text() == md
    with pytest.raises(SystemExit):
        cluster_scaling.main(["--cpus", "2"])  # no --out
    assert isinstance(pd.read_parquet(out), pd.DataFrame)
