"""The committed ledger of which demonstrations each table was made from is current."""

from __future__ import annotations

from scripts.input_sets import OUT, input_sets, recorded_limits, set_names


def test_the_committed_ledger_is_current() -> None:
    assert OUT.read_text() == input_sets(), "rerun: python -m scripts.input_sets"


def test_the_default_study_is_made_from_the_committed_default_set() -> None:
    names = set_names()
    trials = OUT.parents[1] / "default" / "trials.parquet"
    assert "committed default CarRacing" in names[recorded_limits(trials)]


def test_a_table_from_another_set_is_to_rerun_unless_the_ledger_says_why_it_stands() -> None:
    from scripts.input_sets import DEFAULT_LIMITS, REHAB_LIMITS, STANDS, _status

    exact = (41.58, 49.29, 42.06)
    assert _status("results/anything", DEFAULT_LIMITS) == _status("x", REHAB_LIMITS) == "current"
    assert _status("results/anything", exact) == "to rerun on the committed set"
    renderer = "results/ablation/renderer"
    assert _status(renderer, exact) == f"stands: {STANDS[renderer]}"
