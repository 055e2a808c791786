"""Expert rows with their own settings (``Expert.config``): validation, a tiny rehab
comparison of two guideline settings on the same patients through the one evaluation path,
and the committed comparison file of CarRacing's expert settings."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pandas as pd
import pytest

from safe_bc.compare.families import load_comparison
from safe_bc.compare.spec import Comparison, Expert, Method
from safe_bc.data.store import read_table
from safe_bc.selection import SelectionConfig
from safe_bc.tasks.carracing.expert import ExpertConfig
from safe_bc.tasks.rehab.expert import GuidelineConfig
from tests.conftest import rehab_collect

ROOT = Path(__file__).resolve().parents[1]
EXPERT = Method("expert", expert=True)
BOLD = GuidelineConfig(intensity_step=0.05, max_intensity=0.85, hr_hold=0.85, hr_backoff=0.9)
"""A guideline setting that climbs faster than the default (other outcomes on any patient)."""


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (
            lambda: Method("x", selection=SelectionConfig(), expert_config=ExpertConfig()),
            "expert_config= is for expert rows",
        ),
        (lambda: Method("x", expert=True, expert_config={"caution": 1.0}), "a dataclass"),
        (
            lambda: Comparison("t", methods=(EXPERT, Method("e2", expert=True))),
            "same expert",
        ),
        (
            lambda: Comparison("t", methods=(Method("x", expert=True, expert_config=BOLD),)),
            "task 'carracing' takes a ExpertConfig",
        ),
    ],
)
def test_expert_config_validation_one_line(make, match) -> None:
    with pytest.raises(ValueError, match=match) as err:
        make()
    assert "\n" not in str(err.value)


def test_expert_settings_compared_on_the_same_patients(rehab_demos, tmp_path: Path) -> None:
    """The default guideline and a bolder one on the same 3 patients: the bold row's episodes
    are the evaluation path's for its config (not the default's), paired against the default
    expert; a rerun evaluates nothing, a changed setting re-evaluates that row only."""
    from safe_bc.compare.run import run_comparison
    from safe_bc.distributed.evaluate import evaluate
    from safe_bc.rollout.evaluate import EvalConfig, ExpertSource
    from safe_bc.tasks import task_defaults

    comp = Comparison(
        "experts",
        methods=(EXPERT, Method("bold", expert=True, expert_config=BOLD)),
        task="rehab",
        demos=rehab_demos,
        collect=rehab_collect(),
        out=tmp_path,
        episodes=3,
        workers=1,
        reference="expert",
    )
    table = run_comparison(comp, progress=False)
    episodes, _ = read_table(tmp_path / "experts_episodes.parquet")
    assert episodes["method"].tolist() == ["expert"] * 3 + ["bold"] * 3
    assert set(episodes["mode"]) == {"expert"} and set(episodes["train_seed"]) == {0}
    bold = episodes[episodes["method"] == "bold"].reset_index(drop=True)
    default = episodes[episodes["method"] == "expert"].reset_index(drop=True)
    assert (bold["env_seed"] == default["env_seed"]).all()
    assert not bold["reward"].equals(default["reward"])  # the row's own config was used
    task = task_defaults("rehab")
    cfg = EvalConfig(episodes=3, workers=1, seed=0, env=task.env, eps=task.eps)
    direct = evaluate({"bold": ExpertSource(BOLD)}, cfg, limits_of(rehab_demos))
    pd.testing.assert_series_equal(
        bold["reward"], direct.episodes["reward"].reset_index(drop=True), check_exact=True
    )
    row = table.set_index("method").loc["bold"]
    assert row["n_pairs"] == 3
    assert row["d_reward"] == pytest.approx((bold["reward"] - default["reward"]).mean())

    from safe_bc.compare.eval_store import FOLDER
    from tests.test_compare import stored_evaluations

    def mtimes() -> dict[str, int]:
        return {name: (tmp_path / FOLDER / name).stat().st_mtime_ns for name in stored}

    stored = stored_evaluations(tmp_path)
    before = mtimes()
    again = run_comparison(comp, progress=False)
    pd.testing.assert_frame_equal(again, table, check_exact=True)
    assert mtimes() == before and stored_evaluations(tmp_path) == stored
    bolder = replace(BOLD, intensity_step=0.08)
    run_comparison(
        replace(comp, methods=(EXPERT, Method("bold", expert=True, expert_config=bolder))),
        progress=False,
    )  # the other expert is a new evaluation: stored beside the first, which stays
    now = stored_evaluations(tmp_path)
    assert mtimes() == before and sorted(now[n] for n in set(now) - set(stored)) == ["bold seed=0"]


def limits_of(demos: Path):
    """The demonstrations' limits d_s (the comparison's evaluation thresholds)."""
    from safe_bc.data.store import load_demonstrations

    return load_demonstrations(demos).limits


def test_expert_settings_comparison_file() -> None:
    """``tune_jobs/compare/expert.py``: the default expert as the reference and the
    other rows CarRacing expert settings that differ from it, on the held-out tracks."""
    comp = load_comparison(ROOT / "tune_jobs/compare/expert.py")
    assert comp.task == "carracing" and comp.reference == "expert"
    assert comp.method("expert").config is None
    others = [m for m in comp.methods if m.name != "expert"]
    assert others and all(
        isinstance(m, Expert) and isinstance(m.config, ExpertConfig) for m in others
    )
    assert all(m.config != ExpertConfig() for m in others)
    assert len({m.config for m in others}) == len(others)
