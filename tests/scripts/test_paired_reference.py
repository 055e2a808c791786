"""scripts/paired_reference.py pairs every policy with the expert on the same tracks."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pandas as pd
import pytest

from safe_bc.data.store import read_table, write_table_atomic
from scripts.paired_reference import main


def test_pairs_every_seed_with_the_expert_track_by_track(tmp_path: Path, capsys) -> None:
    rows = [{"method": "expert", "train_seed": -1, "env_seed": t, "reward": 900.0 + t,
             "violation_steps": 0.0} for t in range(5)]  # fmt: skip
    rows += [{"method": "both", "train_seed": s, "env_seed": t, "reward": 890.0 + t + s,
              "violation_steps": float(t == 0)} for s in range(3) for t in range(5)]  # fmt: skip
    write_table_atomic(tmp_path / "episodes.parquet", pd.DataFrame(rows),
                       {"command": "x", "git_revision": "abc"})  # fmt: skip
    assert main([str(tmp_path)]) == 0
    paired, meta = read_table(tmp_path / "paired_expert.parquet")
    row = paired.set_index("method").loc["both"]
    assert row["n_pairs"] == 15 and row["d_reward"] == pytest.approx(-9.0)
    assert row["d_violation_steps"] == pytest.approx(0.2)
    assert meta["source"]["git_revision"] == "abc" and "| both" in capsys.readouterr().out
    digest = hashlib.sha256((tmp_path / "episodes.parquet").read_bytes()).hexdigest()
    assert meta["inputs"]["episodes"] == {str(tmp_path / "episodes.parquet"): f"sha256:{digest}"}
