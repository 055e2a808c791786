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


def test_a_table_naming_its_demonstrations_by_path_alone_is_listed_as_unrecorded(tmp_path) -> None:
    """A result table whose metadata names a demonstrations folder but records no limits, no
    digest and no inputs record is listed (as ``unrecorded``, to rerun), not left out; one
    with its inputs recorded, or inside an agent's folder, is not."""
    import json

    import pandas as pd
    import pyarrow as pa
    import pyarrow.parquet as pq

    from scripts.input_sets import UNRECORDED, _status, input_sets, names_demos_only

    def table(path, meta) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        t = pa.Table.from_pandas(pd.DataFrame({"x": [1]}))
        t = t.replace_schema_metadata({b"safe_bc": json.dumps(meta).encode()})
        pq.write_table(t, path)

    (tmp_path / "results" / "demos").mkdir(parents=True)
    table(tmp_path / "results/ablation/old/episodes.parquet", {"demos": "data/demos"})
    table(tmp_path / "results/ablation/new/episodes.parquet", {"demos": "d", "inputs": {}})
    table(tmp_path / "results/ablation/new/runs/agent/curve.parquet", {"demos": "data/demos"})
    assert names_demos_only(tmp_path / "results/ablation/old/episodes.parquet")
    assert not names_demos_only(tmp_path / "results/ablation/new/episodes.parquet")
    assert not names_demos_only(tmp_path / "results/ablation/new/runs/agent/curve.parquet")
    report = input_sets(tmp_path)
    assert "results/ablation/old" in report and "results/ablation/new" not in report
    assert _status("results/ablation/old", UNRECORDED) in report
    assert _status("results/ablation/old", UNRECORDED).startswith("to rerun")
