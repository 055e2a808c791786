"""The Table 1 rerun end to end, on a tiny budget."""

from __future__ import annotations

from pathlib import Path

from safe_bc.bc import BCConfig, NetworkConfig, TrainConfig
from safe_bc.data.store import read_table
from safe_bc.reproduce import ReproduceConfig, run_reproduce


def test_tiny_rerun_writes_table_figures_and_provenance(tiny_demos, tmp_path: Path) -> None:
    cfg = ReproduceConfig(
        demos=tiny_demos,
        out=tmp_path,
        alphas=(0.0, 0.8),
        eps=3.0,
        train_seeds=(0, 1),
        episodes=1,
        workers=2,
        max_steps=60,
        bc=BCConfig(network=NetworkConfig(hidden=16), train=TrainConfig(batches=5, batch_size=8)),
    )
    table = run_reproduce(cfg, progress=False)
    assert table["method"].tolist() == [
        "alpha=0 (rest=all)",
        "alpha=0.8 (rest=all)",
        "alpha=0 (rest=noncritical)",
        "alpha=0.8 (rest=noncritical)",
        "expert",
    ]
    assert (table.loc[table.method != "expert", "n_train_seeds"] == 2).all()
    on_disk, meta = read_table(tmp_path / "table1.parquet")
    assert len(on_disk) == 5
    assert meta["train_seeds"] == [0, 1] and meta["git_revision"]
    assert meta["config"]["eps"] == 3.0
    for name in ("table1.md", "fig4_alpha.png", "fig5_6_traces.png", "table1_episodes.parquet"):
        assert (tmp_path / name).stat().st_size > 0, name
    assert "d_reward" in on_disk and on_disk["d_reward"].notna().sum() == 3
    sel, sel_meta = read_table(tmp_path / "table1_selection" / "selection.parquet")
    assert sel["critical"].sum() == sel_meta["n_critical"] > 0
    assert len(sel_meta["thresholds"]) == 3
    assert "| expert |" in (tmp_path / "table1.md").read_text()

    # re-rendering from the stored episodes gives the same table and records itself
    from safe_bc.reproduce import rerender

    again = rerender(cfg)
    back, meta2 = read_table(tmp_path / "table1.parquet")
    assert back["reward"].tolist() == on_disk["reward"].tolist()
    assert again["method"].tolist() == table["method"].tolist()
    assert meta2["git_revision"] == meta["git_revision"] and "rendered" in meta2
