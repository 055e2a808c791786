"""Result tables under results/ are refused from a dirty git tree unless asked, and recorded."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from safe_bc.data import provenance
from safe_bc.data.store import read_table, read_table_metadata, write_table_atomic


@pytest.fixture
def results(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A stand-in for the checkout's results/ with a dirty tree."""
    monkeypatch.setattr(provenance, "RESULTS", tmp_path / "results")
    monkeypatch.setattr(provenance, "_changed_files", lambda: ["safe_bc/study/spec.py"])
    monkeypatch.delenv(provenance.ALLOW_DIRTY, raising=False)
    return tmp_path / "results"


def test_dirty_tree_cannot_write_a_result_table(results: Path) -> None:
    target = results / "default" / "trials.parquet"
    with pytest.raises(provenance.DirtyTreeError, match=r"SAFE_BC_ALLOW_DIRTY.*recorded"):
        write_table_atomic(target, pd.DataFrame({"a": [1]}), {"command": "x"})
    assert not target.exists()


@pytest.mark.parametrize("value", ["", "0"])
def test_an_empty_or_zero_allowance_is_no_allowance(results, monkeypatch, value) -> None:
    monkeypatch.setenv(provenance.ALLOW_DIRTY, value)
    with pytest.raises(provenance.DirtyTreeError):
        provenance.check_result_write(results / "t.parquet")


def test_an_explicit_allowance_writes_and_records_it(results: Path, monkeypatch) -> None:
    monkeypatch.setenv(provenance.ALLOW_DIRTY, "draft rerun")
    target = results / "default" / "trials.parquet"
    write_table_atomic(target, pd.DataFrame({"a": [1]}), {"command": "x"})
    _, meta = read_table(target)
    assert meta["command"] == "x"
    assert meta["dirty_tree"] == {"allowed_by": "SAFE_BC_ALLOW_DIRTY", "reason": "draft rerun",
                                  "changed_files": ["safe_bc/study/spec.py"]}  # fmt: skip


def test_tables_elsewhere_and_clean_trees_are_not_checked(results, tmp_path, monkeypatch) -> None:
    elsewhere = tmp_path / "scratch" / "t.parquet"
    write_table_atomic(elsewhere, pd.DataFrame({"a": [1]}), {"command": "x"})
    assert "dirty_tree" not in read_table(elsewhere)[1]
    monkeypatch.setattr(provenance, "_changed_files", lambda: [])
    assert provenance.check_result_write(results / "t.parquet") is None


def test_the_real_results_folder_is_the_checkouts() -> None:
    assert Path(provenance.__file__).resolve().parents[2] / "results" == provenance.RESULTS


REPO = Path(__file__).resolve().parents[1]


def _dirty_revisions(value: object) -> list[str]:
    """Every ``git_revision`` ending in ``-dirty`` anywhere in a metadata tree."""
    if isinstance(value, dict):
        found = [v for k, v in value.items() if k == "git_revision" and str(v).endswith("-dirty")]
        return found + [r for v in value.values() for r in _dirty_revisions(v)]
    if isinstance(value, list):
        return [r for v in value for r in _dirty_revisions(v)]
    return []


def test_no_committed_result_records_a_dirty_revision() -> None:
    """Every table and report under results/ comes from a clean commit, or says why not
    (a ``dirty_tree`` allowance recorded by ``$SAFE_BC_ALLOW_DIRTY``)."""
    tables = sorted((REPO / "results").rglob("*.parquet"))
    assert tables, "no result tables found"
    unexplained = []
    for path in tables:
        meta = read_table_metadata(path)
        if _dirty_revisions(meta) and "dirty_tree" not in meta:
            unexplained.append(str(path.relative_to(REPO)))
    for path in sorted((REPO / "results").rglob("*.md")):
        text = path.read_text()
        if "-dirty`" in text or '-dirty"' in text:
            unexplained.append(str(path.relative_to(REPO)))
    assert not unexplained, f"result files from a dirty tree: {unexplained}"


def test_the_dirty_scan_finds_a_dirty_revision(tmp_path: Path) -> None:
    """The scan above can fail: a nested ``-dirty`` revision is found."""
    write_table_atomic(
        tmp_path / "t.parquet",
        pd.DataFrame({"x": [1]}),
        {"provenance": {"git_revision": "abc123-dirty"}},
    )
    assert _dirty_revisions(read_table_metadata(tmp_path / "t.parquet")) == ["abc123-dirty"]
    assert read_table_metadata(tmp_path / "t.parquet")["provenance"]["git_revision"]
