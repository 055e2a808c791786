"""scripts/retrain_check.py: the Table 1 comparison
gives the checked rows the training settings the old script read from the committed table's
metadata, the committed check's committed losses are Table 1's, and (slow) one row retrains to
the committed loss and weights."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from safe_bc.compare.families import load_comparison
from safe_bc.compare.run import run_config
from safe_bc.data.store import read_table
from safe_bc.run_config import RunConfig
from safe_bc.selection import RULES, SelectionConfig
from scripts.retrain_check import ROWS, TABLE1, retrain

ROOT = Path(__file__).resolve().parents[2]
CHECK = ROOT / "results/checks/table1_retrain.parquet"


def _old_run_config(method: dict, seed: int) -> RunConfig:
    """The removed script's settings: the stored selection fields, the default network."""
    keep = ["mode", "alpha", "rest", "eps", *RULES[method["mode"]].params]
    run = RunConfig(SelectionConfig(**{k: method[k] for k in keep}))
    return replace(run, bc=replace(run.bc, train=replace(run.bc.train, seed=seed)))


def _methods(meta: dict) -> dict[str, dict]:
    """Each method's selection fields by name (the comparison runner records a list of
    methods, each with its ``selection``)."""
    methods = meta["config"]["methods"]
    return {m["name"]: m["selection"] for m in methods if m["selection"] is not None}


def test_rows_train_as_the_committed_check_trained_them() -> None:
    comparison = load_comparison(ROOT / TABLE1)
    training, meta = read_table(ROOT / "results/table1_training.parquet")
    committed, check_meta = read_table(CHECK)
    assert [tuple(r) for r in check_meta["rows"]] == list(ROWS)
    for method, seed in ROWS:
        new = run_config(comparison, comparison.method(method), seed)
        assert new == _old_run_config(_methods(meta)[method], seed)
    cells = training.set_index(["method", "train_seed"])["final_loss"]
    want = [cells[(m, s)] for m, s in ROWS]
    assert committed["committed_final_loss"].tolist() == want
    assert (
        committed["identical"].tolist()
        == (committed["retrained_final_loss"] == committed["committed_final_loss"]).tolist()
    )


def _same_machine_type(meta: dict) -> bool:
    """Whether this machine is the type that trained a committed table (its CPU and torch's
    kernel level as recorded; tables from before the CPU was recorded count as another)."""
    from safe_bc.data.provenance import machine_info

    recorded = meta.get("provenance", meta)
    here = machine_info()
    keys = ("cpu_model", "torch_cpu_capability", "torch_version")
    return all(k in recorded and recorded[k] == here[k] for k in keys)


@pytest.mark.slow
def test_one_row_retrains_to_the_committed_loss_and_weights() -> None:
    """Bit identity with committed weights holds on the machine type that trained them only
    (docs/reproducibility.md): elsewhere torch's kernels round differently."""
    comparison = load_comparison(ROOT / TABLE1)
    comparison = replace(comparison, demos=ROOT / comparison.demos)
    training, meta = read_table(ROOT / "results/table1_training.parquet")
    if not _same_machine_type(meta):
        pytest.skip("Table 1 was trained on another machine type (or one it does not record)")
    committed, _ = read_table(CHECK)
    got = retrain(comparison, ROWS[:1], training, meta["git_revision"])
    assert got["identical"].all()
    assert got["weights_sha256"].iloc[0] == committed["weights_sha256"].iloc[0]
