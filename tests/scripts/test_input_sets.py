"""The committed ledger of which demonstrations each table was made from is current."""

from __future__ import annotations

from scripts.input_sets import OUT, input_sets, recorded_limits, set_names


def test_the_committed_ledger_is_current() -> None:
    assert OUT.read_text() == input_sets(), "rerun: python -m scripts.input_sets"


def test_the_default_study_is_made_from_the_committed_default_set() -> None:
    names = set_names()
    trials = OUT.parents[1] / "default" / "trials.parquet"
    assert "committed default CarRacing" in names[recorded_limits(trials)]
