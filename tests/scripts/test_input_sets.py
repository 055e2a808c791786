"""The committed ledger of which demonstrations each table was made from is current."""

from __future__ import annotations

import shutil

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
    # a study's final-phase run (its study's tables name the set), not a table named final_*
    final_run = tmp_path / "results/study/final_selfimprove/t1/seed0/curve.parquet"
    table(final_run, {"demos": "data/demos"})
    assert not names_demos_only(final_run)
    table(tmp_path / "results/study/final_x.parquet", {"demos": "data/demos"})
    assert names_demos_only(tmp_path / "results/study/final_x.parquet")
    # a checkout inside a folder named like a run's (e.g. /work/runs/clone) reads the same
    moved = tmp_path / "runs" / "results/ablation/old/episodes.parquet"
    moved.parent.mkdir(parents=True)
    shutil.copy(tmp_path / "results/ablation/old/episodes.parquet", moved)
    assert names_demos_only(moved)
    report = input_sets(tmp_path)
    assert "results/ablation/old" in report and "results/ablation/new" not in report
    assert "results/study/final_selfimprove" not in report
    assert _status("results/ablation/old", UNRECORDED) in report
    assert _status("results/ablation/old", UNRECORDED).startswith("to rerun")


def test_a_recorded_safety_mean_names_the_set_a_recorded_digest_names() -> None:
    """Where a committed table records both a demonstrations digest and the demonstrations'
    safety mean, the mean identifies the same set as the digest (the rehab mean the rehab
    collection's digest), and the described sets' means differ: the ledger may place a table
    that records only the mean (Table 1 among them) with its set."""
    import json

    import pyarrow.parquet as pq

    from scripts.input_sets import REHAB_LIMITS, ROOT, sets_by_safety_mean

    means = sets_by_safety_mean()
    described = {
        json.loads(p.read_text())["digest"]: json.loads(p.read_text())["safety_mean"]
        for p in sorted((ROOT / "results" / "demos").rglob("summary.json"))
    }
    assert len(set(means.values())) == len(means) == len(described) + 1
    pairs = set()
    for path in sorted((ROOT / "results").rglob("*.parquet")):
        meta = json.loads((pq.read_metadata(path).metadata or {}).get(b"safe_bc", b"{}"))
        demos = (meta.get("inputs") or {}).get("demos") or []
        if len(demos) == 1 and "demo_safety_mean" in meta:
            pairs.add((demos[0]["digest"], round(float(meta["demo_safety_mean"]), 6)))
    assert len(pairs) >= 2
    for digest, mean in pairs:
        if digest in described:
            assert mean == round(described[digest], 6)
        else:
            assert means[mean] == REHAB_LIMITS
    report = OUT.read_text()
    table1 = next(line for line in report.splitlines() if line.startswith("| results   "))
    assert "safety mean" in table1 and "committed default CarRacing set" in table1
