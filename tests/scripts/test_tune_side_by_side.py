"""The side-by-side report says how its runs relate: the default sentence, or the recorded
setting when the runs were not made one after the other on one idle machine."""

from __future__ import annotations

from pathlib import Path

from safe_bc.data.store import read_table
from scripts.tune_side_by_side import markdown

ROOT = Path(__file__).resolve().parents[2]


def test_the_setting_replaces_the_default_sentence() -> None:
    table, meta = read_table(ROOT / "results/checks/make_tune/side_by_side.parquet")
    plain = markdown(table, {**meta, "setting": ""})
    assert "one after the other on one machine (AMD EPYC), nothing else running; made" in plain
    told = markdown(table, {**meta, "setting": "Two sessions"})
    assert told.startswith("# `make tune` side by side\n\nTwo sessions; made by")
    assert "one after the other" not in told.split("\n")[2]


def test_every_run_of_the_recommender_comparison_names_its_demonstrations() -> None:
    folder = ROOT / "results/checks/make_tune/recommender"
    _, meta = read_table(folder / "side_by_side.parquet")
    assert set(meta["inputs"]) == {"old", "oneenv", "new"}
    assert len(set(meta["inputs"].values())) == 1 and all(meta["inputs"].values())
    for path in folder.glob("*/*.parquet"):  # each copy names them too
        assert read_table(path)[1]["inputs"]["demos"]["digest"] == meta["inputs"]["old"], path
