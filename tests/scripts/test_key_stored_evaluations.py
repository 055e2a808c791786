"""The move of stored evaluations from run folders to their content keys."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from safe_bc.data.store import write_table_atomic
from safe_bc.eval_store import episodes_path
from scripts.key_stored_evaluations import output_folder, plan_moves


def test_each_file_goes_to_its_stamps_key_under_its_output_folder(tmp_path: Path) -> None:
    stamp = {"run": {"a": 1}, "eval": {"episodes": 3}, "thresholds": [1.0], "keep_steps": False}
    other = {**stamp, "thresholds": [2.0]}
    frame = pd.DataFrame({"policy": ["x seed=0"], "reward": [1.0]})
    one = Path("res/fam/c_runs/x/seed0/episodes.parquet")
    two = Path("res/fam/d_runs/x/seed0/episodes.parquet")  # the same evaluation, another folder
    three = Path("res/fam/c_runs/x/seed1/episodes.parquet")
    for path, s in ((one, stamp), (three, other)):
        write_table_atomic(tmp_path / path, frame, {"stamp": s})
    (tmp_path / two).parent.mkdir(parents=True)
    (tmp_path / two).write_bytes((tmp_path / one).read_bytes())
    assert output_folder(one) == Path("res/fam")
    moves = plan_moves([one, two, three], root=tmp_path)
    assert moves == [
        (one, episodes_path(Path("res/fam"), stamp)),
        (two, episodes_path(Path("res/fam"), stamp)),
        (three, episodes_path(Path("res/fam"), other)),
    ]
    write_table_atomic(tmp_path / two, frame.assign(reward=2.0), {"stamp": stamp})
    with pytest.raises(ValueError, match="have one stamp but differ"):
        plan_moves([one, two], root=tmp_path)
    with pytest.raises(ValueError, match="under no <runs>_runs folder"):
        output_folder(Path("res/fam/episodes.parquet"))
