"""The observation ablation: the steering-indicator region the evaluation path masks
(safe_bc.rollout.evaluate.MaskedSteering), the comparison file's cells, its report step
(safe_bc.compare.observation_choice) on a small synthetic episode table, and the committed
ablation tables (observation, batch, budget, network, resize) re-derived exactly from their
committed episodes through the step."""

from __future__ import annotations

import importlib.util
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import safe_bc.compare.observation_choice as ablation
from safe_bc.bc.config import PreprocessConfig
from safe_bc.bc.preprocess import STEERING_INDICATOR, preprocess_frames
from safe_bc.compare.families import load_comparison
from safe_bc.compare.run import run_report
from safe_bc.compare.spec import Comparison, Expert, Read
from safe_bc.data.store import read_table, write_table_atomic
from safe_bc.rollout.evaluate import MaskedSteering
from safe_bc.tasks import make_env
from safe_bc.tasks.env_config import EnvConfig

ROOT = Path(__file__).resolve().parents[1]
FAMILY = ROOT / "tune_jobs/compare/observation.py"
_spec = importlib.util.spec_from_file_location("observation", FAMILY)
assert _spec is not None and _spec.loader is not None
OBS = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(OBS)
TABLES = ("summary", "paired", "copycat", "paired_chosen")
"""The step's tables."""


def _steer(env, value: float, steps: int) -> np.ndarray:
    obs = None
    for _ in range(steps):
        obs, *_ = env.step(np.array([value, 0.0, 0.0], np.float32))
    return obs


def test_steering_indicator_lies_inside_the_masked_region():
    """Steer hard left, then hard right, on a real track: the green steering bar moves on both
    sides of column 48 and every pixel it lights lies inside STEERING_INDICATOR."""
    env = make_env(EnvConfig("CarRacing-v3"))
    try:
        env.reset(seed=123)
        for _ in range(60):  # past the zoom-in, some speed
            env.step(np.array([0.0, 0.3, 0.0], np.float32))
        left = _steer(env, -1.0, 8)
        right = _steer(env, 1.0, 16)
    finally:
        env.close()
    rows, cols = STEERING_INDICATOR
    for frame, side in ((left, "left"), (right, "right")):
        bar = frame[84:96].astype(int)
        green = (bar[..., 1] > 200) & (bar[..., 0] < 60) & (bar[..., 2] < 60)
        lit = np.nonzero(green[:, 30:])[1] + 30  # the steering/gyro half of the bar
        assert len(lit), f"no steering indicator lit when steering {side}"
        assert lit.min() >= cols.start and lit.max() < cols.stop, (side, lit.min(), lit.max())
        assert (lit < 48).any() if side == "left" else (lit > 48).any()
    assert rows == slice(84, 96)


class _Recorder:
    def __init__(self) -> None:
        self.seen: list[np.ndarray] = []

    def reset(self, env=None, rng=None) -> None:
        self.seen.clear()

    def act(self, obs, env=None) -> np.ndarray:
        self.seen.append(obs)
        return np.zeros(3, np.float32)


def test_masked_policy_blacks_out_only_the_indicator():
    inner = _Recorder()
    policy = MaskedSteering(inner)
    obs = np.full((96, 96, 3), 77, np.uint8)
    policy.reset()
    policy.act(obs)
    seen = inner.seen[0]
    assert (seen[STEERING_INDICATOR] == 0).all()
    outside = np.ones((96, 96), bool)
    outside[STEERING_INDICATOR] = False
    assert (seen[outside] == 77).all()
    assert (obs == 77).all()  # the caller's frame is untouched


def _episodes() -> pd.DataFrame:
    """A runner's episode table: two cells x 3 seeds x 5 tracks, the bar-kept one also masked
    (row ``bar_grey_k1/steer_masked``), and the expert on the same tracks."""
    rng = np.random.default_rng(0)
    rows = []
    for method, base, viol, seeds in (
        ("nobar_grey_k1", 300.0, 1.0, range(3)),
        ("bar_grey_k1", 900.0, 0.0, range(3)),
        ("bar_grey_k1/steer_masked", 850.0, 0.0, range(3)),
        ("expert", 950.0, 0.0, range(1)),
    ):
        for seed in seeds:
            for track in range(5):
                rows.append(
                    {"policy": f"{method} seed={seed}", "method": method, "train_seed": seed,
                     "env_seed": track, "reward": base + rng.normal(),
                     "any_violation": viol, "violation_steps": 10 * viol,
                     "offroad_steps": 0.0, "safety_mean": 5.0, "steer_autocorr": 0.9,
                     "steer_change": 0.01}
                )  # fmt: skip
    return pd.DataFrame(rows)


def _training() -> pd.DataFrame:
    cells = ("nobar_grey_k1", "bar_grey_k1")
    return pd.DataFrame(
        [
            {"method": c, "train_seed": s, "final_loss": 0.01 * (s + 1)}
            for c in cells
            for s in range(3)
        ]
    )


def _synthetic(out: Path) -> Comparison:
    """A comparison like the family's (two cells, a masked view, the expert) at ``out``."""
    bar = PreprocessConfig(crop_bar=False, mask_steering=False, grayscale=True)
    pre = {"nobar_grey_k1": PreprocessConfig(grayscale=True), "bar_grey_k1": bar}
    rows = [r for c, p in pre.items() for r in OBS.rows(c, OBS.bc(p))]
    assert [r.name for r in rows] == ["nobar_grey_k1", "bar_grey_k1", "bar_grey_k1/steer_masked"]
    return Comparison(
        "synthetic", methods=(*rows, Expert("expert")), out=out, train_seeds=(0, 1, 2),
        episodes=5, eval_seed=10, reference="nobar_grey_k1", title="T", report=OBS.CHOICE,
    )  # fmt: skip


def test_the_step_pairs_cells_and_chooses_the_safe_high_reward_cell() -> None:
    comp = _synthetic(Path("out"))
    meta = {"config": comp.to_dict(), "git_revision": "abc"}
    episodes = Read(_episodes(), {"command": "c", "git_revision": "r"}, Path("e.parquet"))
    files = ablation.report(
        pd.DataFrame(), meta, Path("t.parquet"), "the command",
        episodes=episodes, training=Read(_training(), {}, Path("t_training.parquet")),
    )  # fmt: skip
    assert files.files() == [*(f"{t}.parquet" for t in TABLES), "synthetic.md", "synthetic.png"]
    assert files.meta["chosen"] == "bar_grey_k1" and files.meta["baseline"] == "nobar_grey_k1"
    assert files.meta["batches"] == "2000" and files.meta["seeds"] == [0, 1, 2]
    row = files.tables["paired"].set_index("cell").loc["bar_grey_k1"]
    assert 590 < row["d_reward"] < 610 and row["d_reward_lo"] > 0
    masked = files.tables["copycat"].set_index("cell").loc["bar_grey_k1"]
    assert masked["d_reward_hi"] < 0  # masking cost reward in this synthetic table
    text = files.texts["synthetic.md"]
    assert text.startswith("# T\n") and "**bar_grey_k1**" in text
    assert "0/15" in text and "15/15" in text
    bar = next(line for line in text.splitlines() if line.startswith("| bar_grey_k1 "))
    assert bar.endswith(" 0.02 |")  # the final loss, mean over the seeds'
    assert text.endswith("tables by `the command`; d_s from the demonstrations, eps 2.0 px.\n")
    assert files.figures["synthetic.png"].args["title"] == "T"


def test_the_runner_writes_every_file_of_the_step(tmp_path: Path) -> None:
    """``run_report`` on the synthetic comparison's tables: the four tables with their
    provenance and the digests of the tables read, the Markdown in place of the table's, the
    figure."""
    comp = _synthetic(tmp_path)
    meta = {"config": comp.to_dict(), "command": "compare", "inputs": {"demos": ["d"]}}
    write_table_atomic(tmp_path / "synthetic.parquet", pd.DataFrame({"method": ["x"]}), meta)
    write_table_atomic(tmp_path / "synthetic_episodes.parquet", _episodes(), meta)
    with pytest.raises(FileNotFoundError, match=r"synthetic_training\.parquet is missing"):
        run_report(comp)
    write_table_atomic(tmp_path / "synthetic_training.parquet", _training(), meta)
    (tmp_path / "synthetic.md").write_text("the table's own Markdown\n")
    written = run_report(comp, "the command")
    assert [p.name for p in written] == [
        *(f"{t}.parquet" for t in TABLES),
        "synthetic.md",
        "synthetic.png",
    ]
    summary, made = read_table(tmp_path / "summary.parquet")
    assert made["chosen"] == "bar_grey_k1" and made["command"] == "the command"
    assert made["git_revision"] and made["inputs"]["demos"] == ["d"]
    assert set(made["inputs"]["tables"]) == {
        str(tmp_path / f"synthetic{s}.parquet") for s in ("", "_episodes", "_training")
    }
    assert set(zip(summary["cell"], summary["view"], strict=True)) == {
        ("nobar_grey_k1", "full"), ("bar_grey_k1", "full"), ("bar_grey_k1", "steer_masked"),
        ("expert", "full"),
    }  # fmt: skip
    assert (tmp_path / "synthetic.md").read_text().startswith("# T\n")
    assert (tmp_path / "synthetic.png").read_bytes()[:4] == b"\x89PNG"


def test_mask_steering_preprocessing_equals_masking_the_frame():
    """Training with ``mask_steering`` sees what the evaluation-time mask shows."""
    frames = np.random.default_rng(0).integers(0, 256, (3, 96, 96, 3), dtype=np.uint8)
    masked = frames.copy()
    masked[:, 84:96, 36:62] = 0
    cfg = PreprocessConfig(crop_bar=False, mask_steering=True, grayscale=True)
    plain = PreprocessConfig(crop_bar=False, mask_steering=False, grayscale=True)
    assert preprocess_frames(frames, cfg).equal(preprocess_frames(masked, plain))
    assert not preprocess_frames(frames, plain).equal(preprocess_frames(masked, plain))
    assert OBS.cell_name(cfg) == "bar-nosteer_grey_k1"
    assert len(OBS.all_cells()) == 18


def test_the_preprocessing_default_is_the_committed_ablations_choice():
    """The default follows the measurement: change one and the other must follow."""
    table = ROOT / "results/ablation/observation/summary.parquet"
    summary, meta = read_table(table)
    assert OBS.cell_name(PreprocessConfig()) == meta["chosen"] == ablation.choose(summary)
    assert PreprocessConfig().frame_stack == 1 and PreprocessConfig().resize is None


def _committed_episodes(folder: str) -> tuple[pd.DataFrame, str]:
    """An ablation's committed episodes (the runner's ``<folder>_episodes.parquet``, with its
    training table) as (cell, view) rows, and the cell it pairs with."""
    out = ROOT / "results/ablation" / folder
    raw, source = read_table(out / f"{folder}_episodes.parquet")
    training = read_table(out / f"{folder}_training.parquet")[0]
    return ablation.cells_and_views(raw, training), source["config"]["reference"]


@pytest.mark.parametrize("folder", ["observation", "batch", "budget", "network", "resize"])
def test_committed_ablation_tables_rederive_through_the_step(
    folder: str, tmp_path: Path, monkeypatch
) -> None:
    """The comparison's committed table, episodes and training table copied to the same
    relative path under ``tmp_path``; its report step writes summary, paired, copycat and
    paired_chosen equal to the committed ones, the committed choice, and the committed
    Markdown but its last line (which names the command and the code that made it). The
    resize table was made by an earlier family file (its episodes name it); the step reads
    it all the same."""
    comp = load_comparison(FAMILY, folder)
    (tmp_path / comp.out).mkdir(parents=True)
    for suffix in ("", "_episodes", "_training"):
        name = f"{folder}{suffix}.parquet"
        shutil.copyfile(ROOT / comp.out / name, tmp_path / comp.out / name)
    monkeypatch.chdir(tmp_path)
    run_report(comp, "the command")
    for name in TABLES:
        mine, made = read_table(comp.out / f"{name}.parquet")
        committed, meta = read_table(ROOT / comp.out / f"{name}.parquet")
        if committed.empty:  # no masked cells: both empty
            assert mine.empty and list(mine.columns) == list(committed.columns)
        else:
            pd.testing.assert_frame_equal(mine, committed, check_exact=True)
        assert made["chosen"] == meta["chosen"]
    assert set(made["inputs"]["tables"]) == {
        f"{comp.out}/{folder}{s}.parquet" for s in ("", "_episodes", "_training")
    }
    if folder != "resize":  # the resize episodes predate recording their inputs
        assert made["inputs"]["demos"][0]["digest"].startswith("sha256:")
    text = (comp.out / f"{folder}.md").read_text().splitlines()
    assert text[:-1] == (ROOT / comp.out / f"{folder}.md").read_text().splitlines()[:-1]
    assert "tables by `the command`" in text[-1]


def test_comparison_file_rows_are_the_committed_cells() -> None:
    """tune_jobs/compare/observation.py names its rows as the committed cells (which seed the
    bootstrap), with the committed seeds, and masks exactly the bar-kept cells; the runner's
    row names read back as (cell, view)."""
    raw, _ = _committed_episodes("observation")
    comp = load_comparison(FAMILY, "observation")
    got = {(m.name, comp.seeds_of(m)) for m in comp.methods}
    want = {
        (c if v == "full" else c + OBS.MASKED, tuple(sorted(int(x) for x in s)))
        for (c, v), s in raw.groupby(["cell", "view"])["train_seed"].unique().items()
    }
    assert got == want
    runner = pd.DataFrame({"method": [m.name for m in comp.methods], "train_seed": 0})
    views = ablation.cells_and_views(runner)
    assert set(zip(views["cell"], views["view"], strict=True)) == set(
        raw[["cell", "view"]].drop_duplicates().itertuples(index=False, name=None)
    )
    for out in ("budget", "network"):
        c = load_comparison(FAMILY, out)
        assert {m.name for m in c.methods} == set(_committed_episodes(out)[0]["cell"])


def test_evaluation_path_steering_metrics_match_the_committed_episodes() -> None:
    """``steer_autocorr`` and ``steer_change`` of the one evaluation path equal the committed
    table's for the expert on its first two selection tracks (needs the default
    demonstrations: their expert and limits). The table was made on AMD EPYC; the check was
    shown there (the scripted expert runs no learned net; other machine types not tried)."""
    from safe_bc.distributed.evaluate import evaluate_policies
    from safe_bc.rollout.collect import stored_expert_config
    from safe_bc.rollout.evaluate import EvalConfig, ExpertSource
    from safe_bc.tasks import task_defaults

    raw, _ = read_table(ROOT / "results/ablation/observation/observation_episodes.parquet")
    demos = ROOT / "data/demos"
    if not (demos / "dataset.json").exists():
        pytest.skip(f"no demonstrations at {demos}")
    from safe_bc.data.store import load_demonstrations

    cfg = EvalConfig(episodes=2, workers=0, seed=10, env=task_defaults("carracing").env, eps=2.0)
    sources = {"expert": ExpertSource(stored_expert_config(demos))}
    limits = load_demonstrations(demos).limits
    new, _ = evaluate_policies(sources, cfg, thresholds=limits, progress=False)
    old = raw[raw["method"] == "expert"].set_index("env_seed").loc[new["env_seed"]]
    for c in ("reward", "steer_autocorr", "steer_change", "violation_steps"):
        np.testing.assert_allclose(new[c].to_numpy(float), old[c].to_numpy(float), rtol=1e-9)


def test_the_batch_table_keeps_the_default_batch() -> None:
    """``results/ablation/batch`` (is batch 32 a free cheaper trial?): batch 32 crossed d_s in
    reliably more episodes (no reliable difference in reward), so the rule keeps 64."""
    from safe_bc.bc.config import TrainConfig

    episodes, baseline = _committed_episodes("batch")
    summary, paired, _ = ablation.summarise(episodes, baseline)
    row = paired.set_index("cell").loc["bar-nosteer_rgb_k1@bs32"]
    assert row["d_any_violation_lo"] > 0  # reliably more episodes beyond d_s than batch 64
    assert ablation.choose(summary) == "bar-nosteer_rgb_k1"
    assert TrainConfig().batch_size == 64


def test_every_observation_table_declares_the_step() -> None:
    """The family's tables run the step, each headed by its own title, pairing its reference."""
    titles = {}
    for name in ("observation", "batch", "budget", "network", "resize"):
        c = load_comparison(FAMILY, name)
        assert c.report == OBS.CHOICE and c.out == Path("results/ablation") / name
        titles[name] = c.title
    assert titles["batch"] == "Batch size (CarRacing, plain BC)"
    assert titles["resize"] == "Frame size (CarRacing, plain BC)"
