"""The study's demonstrations step: a set that cannot be the study's is refused before any
collection, and the set is read once for the trials and for its record."""

from __future__ import annotations

from pathlib import Path

import pytest

from safe_bc.data.store import dataset_record, load_demonstrations, read_demonstrations
from safe_bc.rollout.collect import CollectConfig
from safe_bc.study.plan import plan_study
from safe_bc.study.run import _study_demos
from safe_bc.study.spec import Float, StudySpec
from safe_bc.tasks import task_defaults
from safe_bc.tasks.env_config import EnvConfig


def _plan(tmp_path: Path, **kw):
    spec = StudySpec(
        "s", {"selection.alpha": Float(0.0, 1.0)}, trials=1, results=tmp_path / "results",
        storage=str(tmp_path / "ray"), demos=tmp_path / "demos", **kw,
    )  # fmt: skip
    return plan_study(spec, fresh=False, command="", final=False)


def test_demonstrations_of_another_env_are_refused_before_any_collection(tmp_path: Path) -> None:
    rehab = CollectConfig.for_task(task_defaults("rehab"), episodes=1, workers=1)
    plan = _plan(tmp_path, collect=rehab)  # the study evaluates on CarRacing
    with pytest.raises(ValueError, match="RehabPathway-v0 demonstrations but the study evaluates"):
        _study_demos(plan, progress=False)
    other = CollectConfig(episodes=1, workers=1, env=EnvConfig(renderer="exact"))
    with pytest.raises(ValueError, match="drawn by the 'exact' renderer, but the env draws"):
        _study_demos(_plan(tmp_path, collect=other), progress=False)
    assert not (tmp_path / "demos").exists()  # nothing collected


def test_read_demonstrations_is_the_loaded_set_and_its_record(rehab_demos: Path) -> None:
    demos, record = read_demonstrations(rehab_demos)
    assert record == dataset_record(rehab_demos)
    loaded = load_demonstrations(rehab_demos)
    assert (demos.actions == loaded.actions).all() and (demos.costs == loaded.costs).all()
    assert demos.episode_ids.tolist() == loaded.episode_ids.tolist()
    with pytest.raises(ValueError, match="frames must be"):
        read_demonstrations(rehab_demos, frames="disk")  # type: ignore[arg-type]
