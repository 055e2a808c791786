"""The committed default study's time table re-derives from its log and trial table, and names
the demonstrations the study read."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from safe_bc.data.store import read_table
from safe_bc.study.run import read_timing_log
from safe_bc.study.timing import timing_table

STUDY = Path(__file__).resolve().parents[2] / "results" / "default"


def test_the_committed_time_table_re_derives_and_records_its_inputs() -> None:
    trials, tmeta_trials = read_table(STUDY / "trials.parquet")
    table, meta = read_table(STUDY / "timing.parquet")
    again = timing_table(read_timing_log(STUDY / "timing.jsonl"), trials)
    pd.testing.assert_frame_equal(table, again, check_exact=True)
    assert meta["inputs"] == tmeta_trials["inputs"] and meta["inputs"]["demos"]["digest"]
