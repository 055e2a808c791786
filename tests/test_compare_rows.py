"""Comparison rows: a closed set of kinds whose flat view (the recorded configuration and the
stored evaluations' stamps) is what comparisons have always recorded."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from safe_bc.compare import (
    Agent,
    Comparison,
    Expert,
    FromStart,
    Handover,
    Method,
    View,
    family,
    load_comparison,
    load_comparisons,
)
from safe_bc.compare_rows import FLAT_FIELDS, KINDS
from safe_bc.handover import HandoverConfig
from safe_bc.improve.config import ImproveConfig
from safe_bc.selection import SelectionConfig
from safe_bc.selfimprove.config import SelfImproveConfig

ROOT = Path(__file__).parents[1]
FILES = sorted((ROOT / "tune_jobs/compare").glob("*.py"))
NAMES = [(f, name) for f in FILES for name in family(f)]
"""Every comparison of every family file: (file, address)."""


def test_every_stored_evaluation_keeps_its_stamp(monkeypatch) -> None:
    """Every committed evaluation of a comparison cell (``<runs>_runs/.../episodes.parquet``)
    carries the stamp the runner computes for that cell now: stored evaluations stay reused."""
    from safe_bc.data.store import read_table_metadata
    from safe_bc.distributed.compare import _folder, _stamp

    monkeypatch.chdir(ROOT)
    checked = 0
    cells = 0
    for file in FILES:
        for name, c in load_comparisons(file).items():
            for m in c.methods:
                for s in c.seeds_of(m):
                    cells += 1
                    stored = _folder(c, m, s) / "episodes.parquet"
                    if stored.is_file():
                        stamp = read_table_metadata(stored)["stamp"]
                        assert _stamp(c, m, s, stamp["thresholds"]) == stamp, (name, m.name, s)
                        checked += 1
    assert cells == 588  # every cell of every comparison
    assert checked >= 100  # the committed evaluations of every kind of row


@pytest.mark.parametrize(("file", "name"), NAMES, ids=[f"{f.stem}:{n}" for f, n in NAMES])
def test_every_row_reads_as_its_flat_record(file: Path, name: str, monkeypatch) -> None:
    """Each row is one of the kinds; its flat record lists every flat field in order, and the
    flat spelling builds the same row back."""
    monkeypatch.chdir(ROOT)
    c = load_comparison(file, name)
    for m in c.methods:
        assert isinstance(m, KINDS)
        flat = m.flat()
        assert list(flat)[: len(FLAT_FIELDS)] == list(FLAT_FIELDS)
        again = Method(**{k: getattr(m, k) for k in FLAT_FIELDS})
        assert again == m and type(again) is type(m)
    assert [d["name"] for d in c.to_dict()["methods"]] == [m.name for m in c.methods]


def test_the_flat_spelling_gives_each_kind() -> None:
    sel = SelectionConfig(alpha=0.5)
    assert Method("a", selection=sel, seeds=(1,)) == Agent("a", sel, seeds=(1,))
    assert Method("e", expert=True) == Expert("e")
    assert Method("i", improve=ImproveConfig(), start="a") == FromStart("i", "a", ImproveConfig())
    si = Method("s", selfimprove=SelfImproveConfig(), start="a")
    assert si == FromStart("s", "a", SelfImproveConfig()) and si.kind == "selfimprove"
    assert Method("f", fallback_of="a") == Handover("f", "a")
    held = Method("d", fallback_of="a", defer_width=2.0, defer_hold=3, defer_hold_on=("front",))
    assert held == Handover("d", "a", HandoverConfig(2.0, hold=3, hold_on=("front",)))
    assert (held.defer_width, held.defer_hold, held.defer_hold_on) == (2.0, 3, ("front",))
    assert Method("m", masked_of="a") == View("m", "a", masked=True)
    assert Method("v", agents_of="a", renderer="exact") == View("v", "a", renderer="exact")
    for row in (held, si):  # a kind has no flat field of another kind
        assert row.selection is None and not row.expert and row.agents_of == ""
    with pytest.raises(AttributeError):
        _ = held.nothing


def test_a_method_row_names_a_registered_method() -> None:
    with pytest.raises(
        ValueError, match="no registered method takes a config of type SelectionConfig"
    ):
        FromStart("x", "a", SelectionConfig())
    with pytest.raises(ValueError, match="unknown method 'nope'"):
        FromStart("x", "a", ImproveConfig(), method="nope")
    with pytest.raises(ValueError, match="takes a config of type ImproveConfig"):
        FromStart("x", "a", SelfImproveConfig(), method="improve")
    with pytest.raises(ValueError, match="a row is one of"):
        Comparison("t", methods=(Agent("a", SelectionConfig()), "b"))  # type: ignore[arg-type]
    row = dataclasses.replace(Handover("d", "a", HandoverConfig(1.0)), of="b")
    assert row.fallback_of == "b"
