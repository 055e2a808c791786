"""scripts/validation_size: how many held-out episodes a study's validation loss needs, and
the tasks' defaults equal the committed table's choice."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import scripts.validation_size as vs
from safe_bc.data.store import read_table
from safe_bc.tasks import task_defaults

COMMITTED = Path(__file__).resolve().parents[2] / "results" / "validation_size"


def test_the_spread_shrinks_with_more_episodes_and_is_zero_for_equal_ones() -> None:
    rng = np.random.default_rng(1)
    sums, rows = rng.uniform(1, 3, 40) * 30, np.full(40, 30)
    spreads = [vs.resampled_spread(sums, rows, n, 4000, np.random.default_rng(0)) for n in (1, 4)]
    assert spreads[0] > 1.8 * spreads[1] > 0  # about 1/sqrt(n)
    assert vs.resampled_spread(np.full(5, 2.0), np.full(5, 4), 3, 10, rng) == 0.0


def test_the_rule_takes_the_fewest_precise_enough_within_the_cost_else_the_largest_affordable():
    def table(spread, share):
        n = [1, 2, 4, 8][: len(spread)]
        return pd.DataFrame(
            {"task": "t", "n_episodes": n, "rel_spread": spread, "val_share": share}
        )

    assert vs.choose(table([0.3, 0.09, 0.05], [0.01, 0.02, 0.04]))["t"] == 2
    assert vs.choose(table([0.3, 0.2, 0.09], [0.03, 0.06, 0.2]))["t"] == 2  # 4 costs too much
    assert vs.choose(table([0.3, 0.2], [0.5, 0.9]))["t"] == 1  # nothing affordable: the least


@pytest.mark.parametrize("task", ["carracing", "rehab"])
def test_each_tasks_validation_size_is_the_committed_tables_choice(task: str) -> None:
    table, meta = read_table(COMMITTED / "validation_size.parquet")
    rows = table[table["task"] == task]
    assert rows["chosen"].sum() == 1
    assert task_defaults(task).validation_episodes == int(
        rows.loc[rows["chosen"], "n_episodes"].iloc[0]
    )
    assert vs.choose(table)[task] == task_defaults(task).validation_episodes  # the rule re-derives
    assert (
        meta["settings"]["spread_bar"] == vs.SPREAD_BAR
        and meta["settings"]["cost_bar"] == vs.COST_BAR
    )
    assert meta["inputs"][task]["demos"]["digest"].startswith("sha256:")
    assert meta["git_revision"] and "-dirty" not in meta["git_revision"]
    text = (COMMITTED / "validation_size.md").read_text()  # the Markdown re-derives from the table
    assert text == vs.markdown(table, vs.choose(table), vs.made_by(meta))


def test_a_small_rehab_run_writes_the_table_with_its_inputs(tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)  # the task's demonstrations and pool are collected here
    out = tmp_path / "out"
    assert (
        vs.main(
            ["--task", "rehab", "--pool", "4", "--seeds", "1", "--draws", "50", "--out", str(out)]
        )
        == 0
    )
    table, meta = read_table(out / "validation_size.parquet")
    assert list(table["n_episodes"]) == [1, 2, 4] and table["chosen"].sum() == 1
    assert (table["rel_spread"] > 0).all() and (table["val_share"] > 0).all()
    assert meta["inputs"]["rehab"]["validation_pool"]["episodes"] == 4
    assert (out / "validation_size.md").read_text().startswith("# Validation episodes per task")
    curves, _ = read_table(out / "validation_curves.parquet")
    assert set(curves["train_seed"]) == {0} and curves["val_loss"].notna().all()
    assert (out / "validation_size.png").stat().st_size > 0
