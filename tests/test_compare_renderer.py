"""The renderer comparisons on the runner: per-row renderer, view rows (``agents_of``) and
per-row demonstrations; the committed paired tables of results/ablation/renderer/ (made by
the former scripts/renderer_cost.py and renderer_pipeline.py) re-derive exactly from their
committed episode tables through the comparison files and the table builder; a tiny
comparison with an exact row, its raster view and a raster pipeline end to end."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from safe_bc.compare.families import load_comparison
from safe_bc.compare.spec import Comparison, Method, build_table, label_episodes
from safe_bc.data.store import read_table
from safe_bc.selection import SelectionConfig

ROOT = Path(__file__).resolve().parents[1]
COMPARE = ROOT / "tune_jobs/compare"
RENDERER = ROOT / "results/ablation/renderer"
D = [f"d_{m}{s}" for m in ("reward", "violation_steps") for s in ("", "_lo", "_hi")]
PAIRED = ["n_pairs", *D, "seeds_better", "n_seeds_paired"]
BC = Method("bc", selection=SelectionConfig(alpha=0.0))


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: Method("v", agents_of="bc", selection=SelectionConfig()), "exactly one of"),
        (lambda: Method("v", expert=True, demos=Path("d")), "demos= is for BC rows"),
        (lambda: Method("v", agents_of="bc", renderer="vector"), "renderer must be one of"),
        (lambda: Comparison("t", methods=(BC, Method("v", agents_of="nothing"))), "agents_of"),
    ],
)
def test_new_method_fields_one_line(make, match) -> None:
    with pytest.raises(ValueError, match=match) as err:
        make()
    assert "\n" not in str(err.value)


def test_rows_run_in_their_renderer_on_their_own_demos() -> None:
    from safe_bc.compare.run import demos_of, eval_config, own_demos

    comp = load_comparison(COMPARE / "renderer.py", "pipeline")
    exact, raster = comp.methods
    assert eval_config(comp, exact).env.renderer == "exact"
    assert eval_config(comp, raster).env.renderer == "raster"
    assert demos_of(comp, raster) == Path("data/demos_raster") != demos_of(comp, exact)
    sets = own_demos(comp)
    assert sets[Path("data/demos_raster")].env.renderer == "raster"
    assert sets[comp.demos].env.renderer == "exact"  # the exact rows' own set
    view = load_comparison(COMPARE / "renderer.py", "renderer")
    assert demos_of(view, view.method("raster")) == view.demos  # the exact agents' d_s
    assert eval_config(view, view.method("raster")).env.renderer == "raster"


def _rederive(name: str, episodes: pd.DataFrame) -> pd.DataFrame:
    comp = load_comparison(COMPARE / "renderer.py", name)
    table = build_table(comp, label_episodes(comp, episodes))
    return table.set_index("method")


def test_committed_renderer_paired_table_rederives_exactly() -> None:
    """scripts.renderer_cost paired by ``renderer``: the rows of tune_jobs/compare/renderer.py
    are named by it."""
    episodes, meta = read_table(RENDERER / "episodes.parquet")
    committed, _ = read_table(RENDERER / "paired.parquet")
    comp = load_comparison(COMPARE / "renderer.py", "renderer")
    assert (comp.eval_seed, comp.episodes) == (meta["eval_seed"], meta["episodes"])
    assert comp.train_seeds == tuple(sorted(episodes["train_seed"].unique()))
    table = _rederive("renderer", episodes.assign(method=episodes["renderer"]))
    got = table.loc[["raster"], PAIRED].reset_index(drop=True)
    pd.testing.assert_frame_equal(got, committed[PAIRED], check_dtype=False)


@pytest.mark.parametrize("stem", ["pipeline", "pipeline_table1", "pipeline_table1_alpha0"])
def test_committed_pipeline_paired_tables_rederive_exactly(stem: str) -> None:
    episodes, meta = read_table(RENDERER / f"{stem}_episodes.parquet")
    committed, _ = read_table(RENDERER / f"{stem}_paired.parquet")
    comp = load_comparison(COMPARE / "renderer.py", stem)
    assert comp.name == stem and comp.eval_seed == meta["eval_seed"]
    assert comp.train_seeds == tuple(meta["seeds"])
    assert comp.method("raster pipeline").selection.alpha == meta["alpha"]
    table = _rederive(stem, episodes.drop(columns="renderer"))
    got = table.loc[["raster pipeline"], PAIRED].reset_index(drop=True)
    pd.testing.assert_frame_equal(got, committed[PAIRED], check_dtype=False)


def test_tiny_exact_row_raster_view_and_raster_pipeline(ray_session, tmp_path):
    """The view row trains nothing and runs the exact row's agents in the raster env; the
    raster pipeline trains on its own demonstrations and counts against their d_s; a rerun
    reuses every cell."""
    from safe_bc.bc import BCConfig, NetworkConfig, TrainConfig
    from safe_bc.compare.run import run_comparison
    from safe_bc.distributed.collect import collect
    from safe_bc.rollout.collect import CollectConfig
    from safe_bc.tasks.env_config import EnvConfig

    raster_demos, exact_demos = tmp_path / "demos_raster", tmp_path / "demos_exact"
    for renderer, path in (("raster", raster_demos), ("exact", exact_demos)):
        collect(CollectConfig(episodes=2, workers=2, max_steps=150,
                              env=EnvConfig(renderer=renderer)), path, progress=False)  # fmt: skip
    bc = BCConfig(network=NetworkConfig(channels=(4, 4, 4), hidden=8),
                  train=TrainConfig(batches=3, batch_size=8))  # fmt: skip
    sel = SelectionConfig(eps=2.0, alpha=0.0)
    comp = Comparison(
        "tinyrender",
        methods=(
            Method("exact", selection=sel, bc=bc, renderer="exact"),
            Method("raster", agents_of="exact", renderer="raster"),
            Method("raster pipeline", selection=sel, bc=bc, renderer="raster", demos=raster_demos),
        ),
        demos=exact_demos,
        collect=CollectConfig(episodes=2, max_steps=150, env=EnvConfig(renderer="exact")),
        out=tmp_path,
        episodes=2,
        eval_seed=10,
        max_steps=80,
        workers=1,
        reference="exact",
    )
    table = run_comparison(comp, progress=False).set_index("method")
    runs = tmp_path / "tinyrender_runs"
    assert not (runs / "raster/seed0/agent").exists()
    assert (runs / "raster_pipeline/seed0/agent/weights.pt").exists()
    assert table.loc["raster", "n_pairs"] == 2 == table.loc["raster pipeline", "n_pairs"]
    stored = {  # the stored evaluations (named by what made them), by policy
        read_table(p)[0]["policy"].iloc[0]: p
        for p in (tmp_path / "stored_evaluations").glob("*.parquet")
    }
    assert set(stored) == {"exact seed=0", "raster seed=0", "raster pipeline seed=0"}
    stamps = {
        name: read_table(stored[f"{name} seed=0"])[1]["stamp"]
        for name in ("exact", "raster", "raster pipeline")
    }
    assert stamps["exact"]["eval"]["env"]["renderer"] == "exact"
    assert stamps["raster"]["eval"]["env"]["renderer"] == "raster"
    assert stamps["raster"]["thresholds"] == stamps["exact"]["thresholds"]
    assert stamps["raster pipeline"]["thresholds"] != stamps["exact"]["thresholds"]
    assert stamps["raster pipeline"]["run"]["demos"] == str(raster_demos)
    # the table records the demonstrations and the run folders it read, by content
    from safe_bc.data.store import data_digest

    inputs = read_table(tmp_path / "tinyrender.parquet")[1]["inputs"]
    assert [d["digest"] for d in inputs["demos"]] == [
        data_digest(exact_demos),
        data_digest(raster_demos),
    ]
    assert inputs["demos"][1]["collector"]["renderer"] == "raster"
    assert set(inputs["runs"]) == {
        "tinyrender_runs/exact/seed0/agent", "tinyrender_runs/raster_pipeline/seed0/agent",
        *(f"stored_evaluations/{p.name}" for p in stored.values()),
    }  # fmt: skip
    before = stored["raster pipeline seed=0"].stat().st_mtime_ns
    run_comparison(comp, progress=False)
    assert read_table(tmp_path / "tinyrender.parquet")[1]["inputs"] == inputs  # nothing redone
    assert stored["raster pipeline seed=0"].stat().st_mtime_ns == before
