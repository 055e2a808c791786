"""The Table 1 rerun: its rows, the crossed summary, the Markdown, and end to end on a tiny
budget."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from safe_bc.bc import BCConfig, NetworkConfig, TrainConfig
from safe_bc.compare.reproduce import PLAIN_BC, ReproduceConfig, run_reproduce, table1
from safe_bc.compare.spec import render_markdown as _render
from safe_bc.data.store import read_table
from tests.conftest import tiny_collect

META = {"git_revision": "abc", "command": "safe-bc reproduce"}


def render_markdown(table: pd.DataFrame, meta: dict) -> str:
    """Table 1's Markdown with cells' padding removed (``to_markdown`` aligns columns)."""
    md = _render(ReproduceConfig().comparison(), table, meta)
    return re.sub(r" *\| *", " | ", md)


def test_defaults_are_table1_with_enough_seeds() -> None:
    cfg = ReproduceConfig()
    assert cfg.train_seeds == tuple(range(11)) and cfg.episodes == 10
    assert cfg.selection_eps == 2.0  # the task's
    assert [m.name for m in cfg.methods()] == [
        "alpha=0 (rest=all)",
        "alpha=0.1 (rest=all)",
        "alpha=0.5 (rest=all)",
        "alpha=0.8 (rest=all)",
        "alpha=1 (rest=all)",
        "BC-Safe (K=20)",
        "cost-weighted BC (beta=9)",
    ]
    modes = [m.selection.mode for m in cfg.methods()]
    assert modes == ["mix"] * 5 + ["bc_safe", "cost_weighted"]
    assert all(m.selection.eps == 2.0 for m in cfg.methods())
    # the eq. 5 T \ T_eps reading is opt-in; alpha = 1 is the same under both, trained once
    both = ReproduceConfig(readings=("all", "noncritical"), baselines=())
    names = [m.name for m in both.methods()]
    assert len(names) == 9 and "alpha=1 (rest=noncritical)" not in names
    assert "alpha=0 (rest=noncritical)" in names
    only = ReproduceConfig(readings=("noncritical",), alphas=(1.0,), baselines=())
    assert [m.name for m in only.methods()] == ["alpha=1 (rest=noncritical)"]
    assert ReproduceConfig(task="rehab").selection_eps == 0.05


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"alphas": (1.5,)}, "alpha"),
        ({"alphas": (0.5, 0.5)}, "alphas"),
        ({"readings": ()}, "readings"),
        ({"readings": ("some",)}, "reading"),
        ({"baselines": ("osrl",)}, "baseline"),
        ({"train_seeds": ()}, "training seed"),
        ({"train_seeds": (0, 0)}, "train_seeds"),
        ({"episodes": 0}, "episodes"),
        ({"eps": -1.0}, "eps"),
        ({"segment_steps": 0}, "segment_steps"),
        ({"beta": -1.0}, "beta"),
        ({"alphas": (), "baselines": ()}, "no method"),
    ],
)
def test_config_validation(kwargs, match) -> None:
    with pytest.raises(ValueError, match=match):
        ReproduceConfig(**kwargs)


def _episodes(violations: bool) -> pd.DataFrame:
    """4 training seeds x 5 shared tracks for three methods and the expert; the tracks differ
    a lot (a shared effect), alpha 0.5 beats plain BC by 10 on three seeds."""
    rng = np.random.default_rng(0)
    track = rng.normal(0, 100, 5)
    methods = {
        PLAIN_BC: ("mix", 0.0, "all", [0, 0, 0, 0]),
        "alpha=0.5 (rest=all)": ("mix", 0.5, "all", [10, 10, 10, -20]),
        "BC-Safe (K=20)": ("bc_safe", np.nan, "", [-5, -5, -5, -5]),
    }
    rows = []
    for name, (mode, alpha, rest, gain) in methods.items():
        for s in range(4):
            for t in range(5):
                rows.append(
                    {"method": name, "mode": mode, "alpha": alpha, "rest": rest,
                     "train_seed": s, "env_seed": 100 + t, "reward": 500 + track[t] + gain[s]}
                )  # fmt: skip
    for t in range(5):
        rows.append(
            {"method": "expert", "mode": "expert", "alpha": np.nan, "rest": "",
             "train_seed": 0, "env_seed": 100 + t, "reward": 900 + track[t]}
        )  # fmt: skip
    df = pd.DataFrame(rows)
    df["policy"] = df["method"] + " seed=" + df["train_seed"].astype(str)
    df["safety_mean"] = 5.0 + 0.01 * df["reward"]
    df["safety_std"], df["safety_min"] = 1.0, 2.0
    df["offroad_steps"], df["critical_share"] = 3.0, 0.2
    if violations:
        df["violation_steps"] = np.where(df["method"] == "expert", 0.0, 4.0)
        df["any_violation"] = (df["violation_steps"] > 0).astype(float)
        df["violation_rate"] = df["violation_steps"] / 1000
        df["worst_excursion"] = 0.5
    return df


def test_table1_crossed_summary_paired_columns_and_seed_counts() -> None:
    cfg = ReproduceConfig(alphas=(0.0, 0.5), baselines=("bc_safe",))
    table = table1(cfg, _episodes(violations=True))
    assert table["method"].tolist() == [
        PLAIN_BC,
        "alpha=0.5 (rest=all)",
        "BC-Safe (K=20)",
        "expert",
    ]
    t = table.set_index("method")
    # a track effect shared by every method cancels in the paired difference
    assert t.loc["BC-Safe (K=20)", "d_reward"] == pytest.approx(-5.0)
    assert t.loc["BC-Safe (K=20)", "d_reward_hi"] - t.loc["BC-Safe (K=20)", "d_reward_lo"] < 1e-9
    assert (t.loc[PLAIN_BC, "reward_hi"] - t.loc[PLAIN_BC, "reward_lo"]) > 20
    assert t.loc["alpha=0.5 (rest=all)", "d_reward"] == pytest.approx(2.5)
    assert t.loc["alpha=0.5 (rest=all)", "seeds_better"] == 3
    assert t.loc["alpha=0.5 (rest=all)", "n_seeds_paired"] == 4
    assert t.loc["BC-Safe (K=20)", "seeds_better"] == 0
    assert pd.isna(t.loc["expert", "d_reward"]) and pd.isna(t.loc[PLAIN_BC, "d_reward"])
    assert t.loc[PLAIN_BC, ["n_train_seeds", "n_tracks"]].tolist() == [4, 5]
    assert t.loc["expert", ["n_train_seeds", "n_tracks"]].tolist() == [1, 5]
    # violation metrics are summarised when the evaluation produced them
    for m in ("violation_steps", "violation_rate", "any_violation", "worst_excursion"):
        assert m in t and f"{m}_lo" in t
    assert t.loc[PLAIN_BC, "episodes_with_violation"] == 20
    assert t.loc["expert", "episodes_with_violation"] == 0
    assert t.loc["BC-Safe (K=20)", "mode"] == "bc_safe" and pd.isna(
        t.loc["BC-Safe (K=20)", "alpha"]
    )

    md = render_markdown(table, META)
    assert "| violation steps | episodes with a violation |" in md
    assert "| 3/4 seeds better |" in md and "| 0/4 seeds better |" in md
    assert "| 20/20 |" in md and "| 0/5 |" in md and "| 4x5 |" in md
    assert "crossed bootstrap" in md


def test_table1_without_violation_columns() -> None:
    cfg = ReproduceConfig(alphas=(0.0, 0.5), baselines=("bc_safe",))
    table = table1(cfg, _episodes(violations=False).drop(columns="mode"))  # an older run
    assert "violation_steps" not in table and "episodes_with_violation" not in table
    assert table.set_index("method").loc["BC-Safe (K=20)", "mode"] == "mix"  # old runs: no mode
    md = render_markdown(table, META)
    assert "violation" not in md.split("\n")[0]
    # without plain BC there is nothing to pair with
    no_bc = table1(cfg, _episodes(violations=False).query("method != @PLAIN_BC"))
    assert "d_reward" not in no_bc and "seeds better" not in render_markdown(no_bc, META)


def test_cli_arguments_shrink_and_extend_the_table() -> None:
    from safe_bc.cli.commands import parse

    _, job = parse(
        ["reproduce", "--train-seeds", "0", "1", "--episodes", "3", "--readings", "all",
         "noncritical", "--baselines", "--alphas", "0", "0.5", "--out", "/tmp/x"]
    )  # fmt: skip
    cfg = job.config
    assert cfg.train_seeds == (0, 1) and cfg.episodes == 3 and cfg.baselines == ()
    assert [m.name for m in cfg.methods()] == [
        "alpha=0 (rest=all)",
        "alpha=0.5 (rest=all)",
        "alpha=0 (rest=noncritical)",
        "alpha=0.5 (rest=noncritical)",
    ]
    default = parse(["reproduce"])[1].config
    assert default.train_seeds == tuple(range(11)) and default.episodes == 10
    assert default.baselines == ("bc_safe", "cost_weighted") and default.readings == ("all",)
    assert default.alphas == (0.0, 0.1, 0.5, 0.8, 1.0)


def test_tiny_rerun_writes_table_figures_and_provenance(tiny_demos, tmp_path: Path) -> None:
    cfg = ReproduceConfig(
        demos=tiny_demos,
        collect=tiny_collect(),
        out=tmp_path,
        alphas=(0.0, 1.0),
        readings=("all", "noncritical"),
        segment_steps=5,
        eps=3.0,
        train_seeds=(0, 1),
        episodes=2,
        workers=2,
        max_steps=60,
        bc=BCConfig(network=NetworkConfig(hidden=16), train=TrainConfig(batches=5, batch_size=8)),
    )
    table = run_reproduce(cfg, progress=False)
    assert table["method"].tolist() == [
        "alpha=0 (rest=all)",
        "alpha=1 (rest=all)",
        "alpha=0 (rest=noncritical)",
        "BC-Safe (K=5)",
        "cost-weighted BC (beta=9)",
        "expert",
    ]
    agents = table[table.method != "expert"]
    assert (agents["n_train_seeds"] == 2).all() and (table["n_tracks"] == 2).all()
    on_disk, meta = read_table(tmp_path / "table1.parquet")
    assert len(on_disk) == 6
    assert meta["train_seeds"] == [0, 1] and meta["git_revision"]
    assert meta["config"]["eps"] == 3.0
    methods = {m["name"]: m for m in meta["config"]["methods"]}
    assert methods["BC-Safe (K=5)"]["selection"]["mode"] == "bc_safe"
    for name in ("table1.md", "fig4_alpha.png", "fig5_6_traces.png", "table1_episodes.parquet"):
        assert (tmp_path / name).stat().st_size > 0, name
    assert on_disk["d_reward"].notna().sum() == 4
    assert on_disk["seeds_better"].notna().sum() == 4
    assert on_disk["violation_steps"].notna().all() and "episodes_with_violation" in on_disk
    shares = on_disk.set_index("method")["critical_sample_share"]
    assert shares["BC-Safe (K=5)"] == 0.0 and shares["alpha=1 (rest=all)"] == 1.0
    sel, sel_meta = read_table(tmp_path / "table1_selection" / "selection.parquet")
    assert sel["critical"].sum() == sel_meta["n_critical"] > 0
    assert len(sel_meta["thresholds"]) == 3
    md = re.sub(r" *\| *", " | ", (tmp_path / "table1.md").read_text())
    assert "| expert |" in md and "seeds better" in md and "episodes with a violation" in md

    # a rerun resumes: every (method, seed) agent and evaluation is reused, same table
    runs = tmp_path / "table1_runs"
    agent = runs / "alpha=0_rest=all" / "seed1" / "agent" / "config.json"
    stamp = agent.stat().st_mtime_ns
    again = run_reproduce(cfg, progress=False)
    assert agent.stat().st_mtime_ns == stamp
    pd.testing.assert_frame_equal(again, table, check_exact=True)
    stored = [p for p in (tmp_path / "stored_evaluations").glob("*.parquet")
              if not p.name.endswith(".steps.parquet")]  # fmt: skip
    assert len(stored) == 11  # 5 agents x 2 seeds and the expert, one stored evaluation each

    # re-rendering from the stored episodes gives the same table and records itself
    from safe_bc.compare.reproduce import rerender

    again = rerender(cfg)
    back, meta2 = read_table(tmp_path / "table1.parquet")
    assert back["reward"].tolist() == on_disk["reward"].tolist()
    assert again["method"].tolist() == table["method"].tolist()
    assert meta2["git_revision"] == meta["git_revision"] and "rendered" in meta2
