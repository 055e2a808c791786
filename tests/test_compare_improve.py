"""The improvement comparisons on the runner: the committed summary tables of the rehab and
CarRacing improvements and of the margin sweep re-derive exactly from their committed episode
tables through the comparison files (``tune_jobs/compare/``) and the new code; the evaluation
path counts the sessions beyond d_s (the last included) that the old replay counted; the
runner's new spec fields, per-seed table, machines and learning curves."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from safe_bc.compare.families import load_comparison
from safe_bc.compare.spec import (
    Comparison,
    Method,
    build_table,
    display_per_seed,
    label_episodes,
    machines,
    render_markdown,
)
from safe_bc.data.store import read_table
from safe_bc.methods.improve import ImproveConfig
from safe_bc.selection import SelectionConfig
from tests.conftest import rehab_collect, tiny_collect

ROOT = Path(__file__).resolve().parents[1]
COMPARE = ROOT / "tune_jobs/compare"
RENAMED = {  # the old scripts' summary columns -> the runner's
    "total_any_violating_session": "patients_beyond",
    "total_last_session_violation": "last_beyond",
    "total_violation_steps": "eval_path_violation_steps",
    "episodes_with_violation": "episodes_beyond",
}


def _rederive(name: str, folder: str) -> tuple[Comparison, pd.DataFrame, pd.DataFrame]:
    comp = load_comparison(COMPARE / "improve.py", name)
    episodes, _ = read_table(ROOT / folder / "episodes.parquet")
    history, _ = read_table(ROOT / folder / "history.parquet")
    table = build_table(
        comp, label_episodes(comp, episodes), history=history.rename(columns={"mode": "method"})
    )
    return comp, table, label_episodes(comp, episodes)


@pytest.mark.parametrize(
    ("file", "folder"),
    [
        ("improve_rehab", "results/improve/rehab"),
    ],
)
def test_committed_improvement_tables_rederive_exactly(file: str, folder: str) -> None:
    """summary.parquet and paired.parquet (written by the deleted scripts/improve_*.py) from
    the committed episodes and history through the comparison file (the CarRacing tables are
    the runner's, re-derived from their stored evaluations in tests/test_compare_rows.py):
    every committed column, exact (the summary's ``n`` text is ``n_train_seeds`` x
    ``n_tracks``)."""
    comp, table, _ = _rederive(file, folder)
    summary, _ = read_table(ROOT / folder / "summary.parquet")
    paired, _ = read_table(ROOT / folder / "paired.parquet")
    mine = table.rename(columns=RENAMED)
    cols = [c for c in summary.columns if c != "n"]
    for c in RENAMED.values():
        if c in summary:
            mine[c] = mine[c].astype(summary[c].dtype)
    pd.testing.assert_frame_equal(mine[cols], summary[cols], check_exact=True)
    n = [f"{int(a)}x{int(b)}" for a, b in zip(mine["n_train_seeds"], mine["n_tracks"], strict=True)]
    assert n == summary["n"].tolist()
    mine_paired = mine.dropna(subset=["d_reward"])[list(paired.columns)]
    mine_paired = mine_paired.sort_values("method").reset_index(drop=True)
    pd.testing.assert_frame_equal(
        mine_paired, paired.sort_values("method").reset_index(drop=True), check_exact=True,
        check_dtype=False,
    )  # fmt: skip
    assert comp.reference in {"expert", "imitation"}


@pytest.mark.parametrize(
    ("file", "folder"),
    [
        ("improve_carracing", "results/improve/carracing"),
        ("improve_carracing_std003", "results/improve/carracing_std003"),
    ],
)
def test_committed_per_seed_table_rederives(file: str, folder: str) -> None:
    """The per-seed rows of the committed improve.md from the committed episodes (the
    runner's ``<name>_episodes.parquet``, or the deleted scripts' ``episodes.parquet``)."""
    runner = ROOT / folder / "improve_episodes.parquet"
    if runner.exists():
        comp, episodes = load_comparison(COMPARE / "improve.py", file), read_table(runner)[0]
    else:
        comp, _, episodes = _rederive(file, folder)
    lines = (ROOT / folder / "improve.md").read_text().splitlines()
    start = next(i for i, x in enumerate(lines) if x.startswith("Per training seed"))
    committed = [x for x in lines[start + 4 :] if x.startswith("| ")]
    mine = display_per_seed(comp, episodes)
    cells = [[c.strip() for c in line.strip("|").split("|")] for line in committed]
    assert [list(r) for r in mine.astype(str).values] == cells


def test_committed_margin_sweep_rederives_exactly() -> None:
    """sweep.parquet (and the screening's) from the committed selection and test episodes
    through the analysis that stays in scripts/ (scripts/margin_sweep.py)."""
    import scripts.margin_sweep as ms

    sweep = ROOT / "results/improve/rehab/sweep"
    tested = ms.sweep_spec().TESTED
    for tag in ("", "screen_seed0_"):
        selection, _ = read_table(sweep / f"{tag}selection.parquet")
        test, _ = read_table(sweep / f"{tag}test.parquet")
        committed, meta = read_table(sweep / f"{tag}sweep.parquet")
        have = [t for t in tested if t in set(test["method"])]
        assert have == meta["tested"]
        pd.testing.assert_frame_equal(
            ms.sweep_table(selection, test, tested), committed, check_exact=True
        )


def _module(name: str):
    spec = importlib.util.spec_from_file_location(name, COMPARE / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_rehab_improvement_settings_are_the_sweeps_last_choice() -> None:
    """The last tested candidate is the sweep's choice; the rehab comparison runs with its
    margin (rehab's ``TaskSpec.cost_margin``, which ``ImproveConfig`` takes when left unset)
    and its shield zone, shield + Lagrangian."""
    from safe_bc.tasks import task_defaults

    sweep, improve = _module("margin_sweep"), _module("improve")
    chosen = sweep.CANDIDATES[sweep.TESTED[-1]]
    assert ImproveConfig().cost_margin is None
    assert task_defaults("rehab").cost_margin == chosen["cost_margin"]
    assert chosen.get("eps") == improve.SHIELD_EPS
    both = load_comparison(COMPARE / "improve.py", "improve_rehab").method("both").config
    assert (both.shield, both.lagrangian, both.eps) == (True, True, chosen["eps"])
    test = load_comparison(COMPARE / "margin_sweep.py", "sweep_test")
    assert [m.name for m in test.methods][2:] == sweep.TESTED
    assert (test.tracks, test.eval_seed, test.episodes) == ("heldout", 5, 200)


def test_evaluation_path_counts_sessions_beyond_like_the_replay() -> None:
    """``violating_sessions``, ``any_violating_session`` and ``last_session_violation`` of the
    one evaluation path equal the counts of the deleted replay (committed
    results/improve/rehab/episodes.parquet) for the guideline and a start on the 200 held-out
    patients (the start has last sessions beyond d_s, which ``violation_steps`` misses)."""
    from safe_bc.bc import load_checkpoint
    from safe_bc.distributed.evaluate import evaluate_policies
    from safe_bc.rollout.evaluate import EvalConfig, ExpertSource, NetSource
    from safe_bc.tasks import task_defaults

    committed, meta = read_table(ROOT / "results/improve/rehab/episodes.parquet")
    task = task_defaults("rehab")
    start = ROOT / "results/improve/rehab/starts/seed0"
    sources = {
        "expert": ExpertSource(task.expert),
        "imitation/0": NetSource.from_model(*load_checkpoint(start)),
    }
    cfg = EvalConfig(episodes=200, workers=0, seed=5, env=task.env, eps=0.05)
    new, _ = evaluate_policies(sources, cfg, thresholds=np.array(meta["limits"]), progress=False)
    cols = ["violating_sessions", "any_violating_session", "last_session_violation"]
    for key in sources:
        mine = new[new["policy"] == key].set_index("env_seed")
        old = committed[committed["policy"] == key].set_index("env_seed").loc[mine.index]
        np.testing.assert_allclose(mine["reward"], old["reward"], atol=1e-4)
        for c in cols:
            np.testing.assert_array_equal(mine[c].to_numpy(float), old[c].to_numpy(float))
    last = new.loc[new["policy"] == "imitation/0", "last_session_violation"].sum()
    assert last > 0  # the case the state-before count cannot see


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"totals": ("sessions",)}, "totals"),
        ({"tracks": "train"}, "tracks"),
        ({"first_track": -1}, "first_track"),
    ],
)
def test_new_spec_fields_one_line(kw, match) -> None:
    with pytest.raises(ValueError, match=match):
        Comparison("t", methods=(Method("b", selection=SelectionConfig()),), **kw)


def test_validation_tracks_are_the_runs_validation_patients() -> None:
    from safe_bc.compare.run import track_seeds
    from safe_bc.methods.improve import validation_seeds

    comp = load_comparison(COMPARE / "margin_sweep.py", "sweep_selection")
    assert track_seeds(comp) == validation_seeds(1024 + 512)[1024:]
    heldout = load_comparison(COMPARE / "improve.py", "improve_rehab")
    assert len(set(track_seeds(heldout)) & set(track_seeds(comp))) == 0


def test_markdown_names_rows_by_label_and_lists_machines(tmp_path: Path) -> None:
    """Labels in the table, the expert-as-reference note, the per-seed table, the machines
    and the learning-curves figure (drawn from the committed history)."""
    from safe_bc.plots import plot_learning_curves

    comp, table, episodes = _rederive("improve_rehab", "results/improve/rehab")
    meta = {
        "git_revision": "r",
        "command": "c",
        "run_machines": machines([{"machine": "m", "cpus": 2, "python": "3"}] * 2),
        "eval_machines": "",
    }
    md = render_markdown(comp, table, meta, episodes)
    assert "| guideline clinician (expert) |" in md and "| shield only " in md
    assert "stands in for every seed" in md
    assert "Improvement runs made on: m (2 CPUs, python 3): 2." in md
    assert "![learning curves](learning_curves.png)" in md
    assert "Per training seed" not in md  # only where asked for (per_seed)
    history, _ = read_table(ROOT / "results/improve/rehab/history.parquet")
    out = plot_learning_curves(
        history.rename(columns={"mode": "method"}), {"expert": 13.5}, tmp_path / "c.png",
        labels={"both": "shield + Lagrangian"},
    )  # fmt: skip
    assert out.stat().st_size > 10_000


def test_tiny_fallback_rows_share_the_runs_of_another_comparison(rehab_demos, tmp_path):
    """A diagnostic comparison with ``runs=`` another's stem reuses its agents and runs
    (nothing retrained) and evaluates its fallback rows (the expert in critical states)."""
    from dataclasses import replace

    from safe_bc.bc import BCConfig, NetworkConfig, TrainConfig
    from safe_bc.compare.eval_store import FOLDER
    from safe_bc.compare.run import run_comparison
    from tests.test_compare import TINY, stored_evaluations

    base = Comparison(
        "tiny",
        methods=(
            Method("expert", expert=True),
            Method("start", selection=SelectionConfig(eps=0.05, alpha=0.5)),
            Method("improved", improve=TINY, start="start"),
        ),
        task="rehab",
        demos=rehab_demos,
        collect=rehab_collect(),
        out=tmp_path,
        train_seeds=(0,),
        episodes=3,
        workers=0,
        bc=BCConfig(network=NetworkConfig(hidden=16), train=TrainConfig(batches=5, batch_size=8)),
    )
    run_comparison(base, progress=False)
    weights = tmp_path / "tiny_runs/start/seed0/agent/config.json"
    run = tmp_path / "tiny_runs/improved/seed0/improve"
    before = weights.stat().st_mtime_ns, sorted(p.stat().st_mtime_ns for p in run.rglob("*"))
    diag = replace(
        base,
        name="diag",
        runs="tiny",
        methods=(
            *base.methods,
            Method("start+expert", fallback_of="start", label="start, expert fallback"),
            Method("improved+expert", fallback_of="improved"),
        ),
        reference="start",
    )
    table = run_comparison(diag, progress=False)
    after = weights.stat().st_mtime_ns, sorted(p.stat().st_mtime_ns for p in run.rglob("*"))
    assert after == before
    assert not (tmp_path / "diag_runs").exists()
    assert set(table["mode"]) == {"expert", "mix", "improve", "fallback"}
    assert table.set_index("method").loc["start+expert", "n_pairs"] == 3
    assert "start, expert fallback" in (tmp_path / "diag.md").read_text()
    with pytest.raises(ValueError, match="fallback_of"):
        Comparison("t", methods=(Method("f", fallback_of="nothing"),))
    # deferral rows: the expert acts within the width of d_s; a width beyond every
    # cost hands every step to the expert, whose own episodes they then are
    defer = replace(
        diag,
        name="defer",
        methods=(
            *base.methods,
            Method("start+defer0", fallback_of="start", defer_width=0.0),
            Method("improved+deferall", fallback_of="improved", defer_width=1e9),
            Method("start+defer0held", fallback_of="start", defer_width=0.0, defer_hold=5),
            Method(
                "start+defer0heldon",
                fallback_of="start",
                defer_width=0.0,
                defer_hold=5,
                defer_hold_on=("fatigue",),
            ),
        ),
        reference="expert",
    )
    table = run_comparison(defer, progress=False).set_index("method")
    episodes, _ = read_table(tmp_path / "defer_episodes.parquet")
    by = episodes.set_index(["method", "env_seed"])
    assert (by.loc["improved+deferall", "deferred_share"] == 1.0).all()
    pd.testing.assert_series_equal(
        by.loc["improved+deferall", "reward"], by.loc["expert", "reward"], check_names=False
    )
    assert table.loc["improved+deferall", "deferred_share"] == 1.0
    assert np.isnan(table.loc["start", "deferred_share"])
    assert "steps deferred" in (tmp_path / "defer.md").read_text()
    files = {policy: name for name, policy in stored_evaluations(tmp_path).items()}
    stamps = {  # a held row's stamp names its hold; rows without one keep their old stamps
        name: read_table(tmp_path / FOLDER / files[f"{name} seed=0"])[1]
        for name in ("start+defer0", "start+defer0held", "start+defer0heldon")
    }
    assert stamps["start+defer0held"]["stamp"]["run"]["hold"] == 5
    assert "hold" not in stamps["start+defer0"]["stamp"]["run"]
    assert "hold_on" not in stamps["start+defer0held"]["stamp"]["run"]
    assert stamps["start+defer0heldon"]["stamp"]["run"]["hold_on"] == ["fatigue"]
    held = by.loc["start+defer0held", "deferred_share"]  # a hold on one dimension holds less
    assert (by.loc["start+defer0heldon", "deferred_share"] <= held).all()
    with pytest.raises(ValueError, match="defer_hold_on= names the dimensions"):
        Method("d", fallback_of="start", defer_width=1.0, defer_hold_on=("fatigue",))
    with pytest.raises(ValueError, match="defer_hold= is a number of steps"):
        Method("d", fallback_of="start", defer_hold=3)
    with pytest.raises(ValueError, match="defer_lookahead= is a number of steps"):
        Method("d", fallback_of="start", defer_width=1.0, defer_lookahead=-1)
    with pytest.raises(ValueError, match="defer_width= is a finite width"):
        Method("d", selection=SelectionConfig(), defer_width=1.0)
    with pytest.raises(ValueError, match="defer_width= is a finite width"):
        Method("d", fallback_of="start", defer_width=-1.0)


def test_tiny_masked_row_evaluates_the_same_agent_with_the_indicator_black(
    tiny_demos, tmp_path: Path
) -> None:
    """A bar-kept BC row and its masked row on CarRacing: the masked row trains nothing, runs
    the row's agent on the same tracks, and the evaluation path records the steering-follow
    metrics; the runner's rows read back as (cell, view) for the observation ablation's report
    step."""
    from safe_bc.bc import BCConfig, NetworkConfig, PreprocessConfig, TrainConfig
    from safe_bc.compare.observation_choice import cells_and_views
    from safe_bc.compare.run import run_comparison

    pre = PreprocessConfig(crop_bar=False, mask_steering=False)
    bc = BCConfig(preprocess=pre, network=NetworkConfig(channels=(4, 4, 4), hidden=8),
                  train=TrainConfig(batches=3, batch_size=8))  # fmt: skip
    comp = Comparison(
        "tinyobs",
        methods=(
            Method("bar_rgb_k1", selection=SelectionConfig(eps=2.0, alpha=0.0), bc=bc),
            Method("bar_rgb_k1/steer_masked", masked_of="bar_rgb_k1"),
        ),
        demos=tiny_demos,
        collect=tiny_collect(),
        out=tmp_path,
        episodes=2,
        eval_seed=10,
        max_steps=80,
        workers=1,
        reference="bar_rgb_k1",
    )
    table = run_comparison(comp, progress=False)
    assert not (tmp_path / "tinyobs_runs/bar_rgb_k1_steer_masked/seed0/agent").exists()
    episodes, _ = read_table(tmp_path / "tinyobs_episodes.parquet")
    assert episodes["steer_change"].notna().all()
    assert table.set_index("method").loc["bar_rgb_k1/steer_masked", "n_pairs"] == 2
    training, _ = read_table(tmp_path / "tinyobs_training.parquet")
    views = cells_and_views(episodes, training)
    assert set(views["cell"]) == {"bar_rgb_k1"} and views["final_loss"].notna().all()
    assert sorted(set(views["view"])) == ["full", "steer_masked"]
