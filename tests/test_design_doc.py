"""docs/design.md is current: its layout names every module of the package, and every module
path it names exists."""

from __future__ import annotations

import re
from pathlib import Path

import safe_bc

ROOT = Path(safe_bc.__file__).resolve().parent
DESIGN = ROOT.parent / "docs" / "design.md"


def layout_section() -> str:
    return DESIGN.read_text().split("\n## Layout", 1)[1].split("\n## ", 1)[0]


def modules() -> set[str]:
    return {p.relative_to(ROOT).as_posix() for p in ROOT.rglob("*.py") if p.name != "__init__.py"}


def named() -> set[str]:
    return set(re.findall(r"^\| `([\w/]+\.py)` \|", layout_section(), flags=re.M))


def test_the_layout_names_every_module():
    assert sorted(modules() - named()) == []


def test_every_module_the_layout_names_exists():
    assert sorted(named() - modules()) == []


def test_the_check_reads_the_table():
    assert "study/run.py" in named() and "metrics.py" in named()
