"""The family files are plain configs: they import only the package and the standard
library (never each other), and declaring them reads no result."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

from safe_bc.compare.families import family

ROOT = Path(__file__).resolve().parents[1]
FAMILIES = sorted((ROOT / "tune_jobs/compare").glob("*.py"))


@pytest.mark.parametrize("path", FAMILIES, ids=[p.stem for p in FAMILIES])
def test_a_family_imports_only_the_package_and_the_standard_library(path: Path) -> None:
    tree = ast.parse(path.read_text())
    roots = {
        name.split(".")[0]
        for node in ast.walk(tree)
        if isinstance(node, ast.Import | ast.ImportFrom)
        for name in (
            [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or "."]
        )
    }
    assert roots <= {"safe_bc"} | set(sys.stdlib_module_names), roots
    assert "importlib" not in roots and "__file__" not in path.read_text()


def test_declaring_the_families_reads_no_table(tmp_path: Path, monkeypatch) -> None:
    """Declared from an empty folder with every table reader broken: nothing is read."""
    import pandas as pd

    import safe_bc.data.store as store

    def no_read(*_: object, **__: object) -> None:
        raise AssertionError("a family read a table while being declared")

    monkeypatch.setattr(pd, "read_parquet", no_read)
    monkeypatch.setattr(store, "read_table", no_read)
    monkeypatch.chdir(tmp_path)
    declared = {p.stem: family(p) for p in FAMILIES}
    assert sum(len(d) for d in declared.values()) == 69  # every one made
