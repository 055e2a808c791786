"""A study run's plan (``safe_bc.study.plan``) is made from the spec alone, without Ray or a
file, and holds what the driver's phases read."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pandas as pd
import pytest

from safe_bc.handover import HandoverConfig
from safe_bc.seeds import VALIDATION_SEED
from safe_bc.study.plan import (
    constraint_bars,
    plan_study,
    run_identity,
    trials_meta,
    validation_path,
)
from safe_bc.study.spec import Float, StudySpec


def _spec(tmp_path: Path, **kw) -> StudySpec:
    base = StudySpec(
        "s", {"selection.alpha": Float(0.0, 1.0)}, trials=3, results=tmp_path / "results",
        storage=str(tmp_path / "ray"), demos=tmp_path / "demos", rollout_workers=2,
    )  # fmt: skip
    return replace(base, **kw)


def test_the_plan_places_every_output_and_touches_no_file(tmp_path: Path) -> None:
    plan = plan_study(_spec(tmp_path), fresh=True, command="safe-bc tune s.py", final=False)
    assert plan.out == tmp_path / "results" / "s"
    assert plan.exp_path == f"{tmp_path / 'ray'}/s" and plan.local
    assert plan.optuna_url == f"sqlite:///{plan.out / 'optuna.db'}"
    assert plan.demos == tmp_path / "demos"
    assert (plan.fresh, plan.command, plan.final) == (True, "safe-bc tune s.py", False)
    assert plan.trial_resources == ({"CPU": 1.0}, {"CPU": 1.0}, {"CPU": 1.0})
    assert plan.collect.env == plan.spec.env  # the task's default collection
    assert "px to the grass" in plan.pareto_axes["safety_label"]
    assert list(tmp_path.iterdir()) == []


def test_a_resource_change_keeps_the_settings_and_the_finished_mark(tmp_path: Path) -> None:
    plan = plan_study(_spec(tmp_path), fresh=False, command="", final=True)
    faster = plan_study(
        _spec(tmp_path, max_concurrent=4, cpus_per_trial=0.5), fresh=False, command="", final=True
    )
    assert faster.settings == plan.settings and "max_concurrent" not in plan.settings
    assert faster.finished != plan.finished  # the mark keeps the whole summary
    longer = plan_study(_spec(tmp_path, max_steps=160), fresh=False, command="", final=True)
    assert longer.settings != plan.settings


def test_bars_identity_and_metadata_follow_the_plan(tmp_path: Path) -> None:
    spec = _spec(tmp_path, threshold=None, handover=HandoverConfig(1.0), deferred_share_limit=0.2)
    plan = plan_study(spec, fresh=False, command="c", final=True)
    threshold, limits = constraint_bars(spec, 2.5, {"a": 1.0})
    assert threshold == 2.5 and limits.deferred_share_limit == 0.2
    assert constraint_bars(replace(spec, threshold=4.0), 2.5, {})[0] == 4.0
    inputs = {"demos": {"digest": "sha256:x"}}
    identity = run_identity(plan, threshold, [1.0], inputs)
    assert identity == {
        "trials": 3, "threshold": 2.5, "limits": [1.0], "batch_size": spec.batch_size,
        "demos_digest": "sha256:x", "experiment_path": plan.exp_path, "settings": plan.settings,
    }  # fmt: skip
    trials = pd.DataFrame({"eval_seeds": ["7,8"]})
    meta = trials_meta(
        plan, trials, threshold=threshold, limits=limits, expert_safety=2.5, cost_limits=[1.0],
        inputs=inputs, complete=True, lost=[], provenance={},
    )  # fmt: skip
    assert meta["seeds"]["eval_seeds"] == [7, 8] and meta["command"] == "c"
    assert meta["deferred_share_limit"] == 0.2 and meta["study"] == plan.summary
    empty = trials_meta(
        plan, trials.iloc[:0], threshold=threshold, limits=limits, expert_safety=2.5,
        cost_limits=[1.0], inputs=inputs, complete=False, lost=[], provenance={},
    )  # fmt: skip
    assert empty["seeds"]["eval_seeds"] == []


@pytest.mark.parametrize("name", ["default", "default_one_seed", "rehab"])
def test_a_committed_studys_settings_re_derive_from_its_study_file(name: str) -> None:
    """What the committed study's tables record as its settings (the identity a resume
    compares) is what its study file gives now: the task defaults a file leaves unset (the
    base's eps, the handover) resolve to the values it ran with."""
    from safe_bc.data.store import read_table
    from safe_bc.study.spec import load_study, settings_of

    repo = Path(__file__).resolve().parents[1]
    _, meta = read_table(repo / "results" / name / "trials.parquet")
    spec = load_study(repo / "tune_jobs" / f"{name}.py")
    now, recorded = settings_of(spec.summary()), settings_of(meta["study"])
    assert {k: now[k] for k in recorded} == recorded
    assert all(now[k] is None for k in set(now) - set(recorded))  # fields the record lacks


def test_the_study_record_names_a_storage_inside_the_repository_relative_to_it(
    tmp_path: Path,
) -> None:
    from safe_bc.data.provenance import RESULTS

    inside = plan_study(
        replace(_spec(tmp_path), storage=str(RESULTS / "ray")), fresh=False, command="", final=True
    )
    identity = run_identity(inside, 1.0, [1.0], {"demos": {"digest": "sha256:x"}})
    assert identity["experiment_path"] == f"results/ray/{inside.spec.name}"
    outside = plan_study(_spec(tmp_path), fresh=False, command="", final=True)
    assert outside.exp_path.startswith(str(tmp_path))  # elsewhere: absolute, as it was
    assert run_identity(outside, 1.0, [1.0], {"demos": {"digest": "x"}})["experiment_path"] == (
        outside.exp_path
    )


def test_the_validation_set_is_the_tasks_size_collected_beside_the_demos_on_tracks_of_its_own(
    tmp_path: Path,
) -> None:
    from safe_bc.tasks import task_defaults

    for task in ("carracing", "rehab"):
        n = task_defaults(task).validation_episodes
        spec = _spec(tmp_path, env=task_defaults(task).env, space={}, validation_episodes="task")
        assert spec.validation_episodes == n >= 1  # "task", resolved when the spec is made
        plan = plan_study(spec, fresh=True, command="", final=True)
        assert (
            plan.validation == validation_path(tmp_path / "demos") == tmp_path / "demos_validation"
        )
        made = plan.validation_collect
        assert made == replace(plan.collect, episodes=n, seed=VALIDATION_SEED) != plan.collect
        assert plan.summary["validation_episodes"] == n  # recorded with every table
        assert "validation_episodes" not in plan.settings  # the numbers do not depend on it
    off = plan_study(_spec(tmp_path, validation_episodes=0), fresh=True, command="", final=True)
    assert off.validation is None and off.validation_collect is None
    named = _spec(tmp_path, validation_demos=tmp_path / "other")
    given = plan_study(named, fresh=True, command="", final=True)
    assert given.validation == tmp_path / "other" and given.validation_collect is None
    inputs = {"demos": {"digest": "a"}, "validation": {"digest": "b"}}
    assert run_identity(plan, 1.0, [1.0], inputs)["validation_digest"] == "b"  # a resume: same set
    for bad in (-1, 1.5, True, "all"):
        with pytest.raises(ValueError, match="validation_episodes"):
            _spec(tmp_path, validation_episodes=bad)
