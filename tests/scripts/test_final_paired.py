"""scripts/final_paired.py derives the paired table of a finished study from its episodes."""

from __future__ import annotations

from pathlib import Path

from safe_bc.data.store import read_table, write_table_atomic
from scripts.final_paired import main
from tests.distributed.test_final import episodes


def test_writes_the_paired_table_with_provenance(tmp_path: Path, capsys) -> None:
    meta = {"command": "safe-bc tune x", "final_design": {"final_seed": 2},
            "provenance": {"git_revision": "abc"}}  # fmt: skip
    write_table_atomic(tmp_path / "final_episodes.parquet", episodes(), meta)
    assert main([str(tmp_path)]) == 0
    table, out_meta = read_table(tmp_path / "final_paired.parquet")
    assert len(table) == 3 and out_meta["bootstrap_seed"] == 2
    assert out_meta["source"]["provenance"]["git_revision"] == "abc"
    assert "| a " in capsys.readouterr().out
