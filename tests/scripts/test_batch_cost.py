"""scripts/batch_cost.py replays a study's trial durations with and without batches."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from safe_bc.data.store import write_table_atomic
from safe_bc.study.spec import schedule_seconds
from scripts.batch_cost import main


def test_batches_wait_for_their_slowest_trial() -> None:
    assert schedule_seconds([5, 5, 5, 5], slots=2, batch_size=2) == 10.0
    assert schedule_seconds([9, 1, 1, 1, 1, 9], slots=2) == 13.0  # 1+1+1+1 then 9
    assert schedule_seconds([9, 1, 1, 1, 1, 9], slots=2, batch_size=2) == 19.0
    assert schedule_seconds([3, 4], slots=1) == 7.0
    with pytest.raises(ValueError, match="slots"):
        schedule_seconds([1.0], slots=0)


def test_reads_the_trial_table(tmp_path: Path, capsys) -> None:
    trials = pd.DataFrame({"trial_number": [1, 0, 2, 3], "duration_s": [1.0, 9.0, 1.0, 9.0]})
    write_table_atomic(tmp_path / "trials.parquet", trials,
                       {"study": {"max_concurrent": 2, "batch_size": 2}})  # fmt: skip
    assert main([str(tmp_path)]) == 0
    assert "18 s in batches of 2, 11 s unbatched (+64%)" in capsys.readouterr().out


def test_a_study_without_max_concurrent_needs_slots(tmp_path: Path, capsys) -> None:
    trials = pd.DataFrame({"trial_number": [0, 1], "duration_s": [4.0, 2.0]})
    write_table_atomic(tmp_path / "trials.parquet", trials,
                       {"study": {"max_concurrent": None, "batch_size": 2}})  # fmt: skip
    assert main([str(tmp_path)]) == 2
    assert "give --slots N" in capsys.readouterr().err
    assert main([str(tmp_path), "--slots", "1"]) == 0
    assert "on 1 slots: 6 s in batches of 2" in capsys.readouterr().out
