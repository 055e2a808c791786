"""The study as data (no Ray): spec validation, parameters, feasibility, table, winner, figure."""

from __future__ import annotations

import math
import re
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from safe_bc.plots import plot_pareto
from safe_bc.run_config import RunConfig
from safe_bc.study.spec import (
    TRIAL_INFO,
    Choice,
    Float,
    Int,
    StudySpec,
    apply_params,
    choose_winner,
    constraint_value,
    is_feasible,
    load_study,
    pareto_mask,
    summary_lines,
    trial_metrics,
    trial_table,
)

REPO = Path(__file__).resolve().parent.parent
PARAMS = ("selection.alpha", "bc.network.channels")


def spec(**kw) -> StudySpec:
    space = {"selection.alpha": Float(0.0, 1.0), "bc.network.channels": Choice(((8, 16, 16),))}
    return StudySpec("t", space, **kw)


def test_apply_params_sets_nested_fields_and_decodes_values() -> None:
    base = spec().base
    cfg = apply_params(
        base,
        {
            "selection.eps": 2,
            "selection.rest": "noncritical",
            "bc.network.channels": "4-8-8",
            "bc.network.hidden": 64.0,  # a float from a table column
            "bc.preprocess.grayscale": np.bool_(False),
            "bc.preprocess.frame_stack": np.int64(2),
            "bc.train.lr": 1e-3,
        },
    )
    assert cfg.selection.eps == 2.0 and isinstance(cfg.selection.eps, float)
    assert cfg.selection.rest == "noncritical"
    assert cfg.bc.network.channels == (4, 8, 8)
    assert cfg.bc.network.hidden == 64 and isinstance(cfg.bc.network.hidden, int)
    assert cfg.bc.preprocess.grayscale is False
    assert cfg.bc.preprocess.frame_stack == 2 and cfg.bc.train.lr == 1e-3
    assert base.bc.network.channels == (16, 32, 32)  # the base is untouched


@pytest.mark.parametrize(
    ("params", "match"),
    [
        ({"selection.nope": 1}, "unknown parameter"),
        ({"bc.optimizer.lr": 1}, "unknown parameter"),
        ({"selection.alpha": 1.5}, "alpha"),
        ({"bc.network.hidden": 1.5}, "integer"),
        ({"selection.rest": "some"}, "rest"),
    ],
)
def test_apply_params_rejects_bad_values(params, match) -> None:
    with pytest.raises(ValueError, match=match):
        apply_params(spec().base, params)


def test_spec_validates_space_and_budget() -> None:
    with pytest.raises(ValueError, match="channels"):  # 2 layers, but 3 kernel sizes
        StudySpec("t", {"bc.network.channels": Choice(((8, 16), (16, 32, 32)))})
    with pytest.raises(ValueError, match="alpha"):
        StudySpec("t", {"selection.alpha": Float(0.0, 2.0)})
    with pytest.raises(ValueError, match="unknown parameter"):
        StudySpec("t", {"bc.train.momentum": Float(0.0, 1.0)})
    with pytest.raises(ValueError, match="final_seed"):
        spec(eval_seed=3, final_seed=3)
    with pytest.raises(ValueError, match="trials"):
        spec(trials=0)
    for bad in (0, 1.5, True):
        with pytest.raises(ValueError, match="max_concurrent"):
            spec(max_concurrent=bad)
    with pytest.raises(ValueError, match="name"):
        StudySpec("a b", {})
    with pytest.raises(ValueError, match="log"):
        Float(0.0, 1.0, log=True)
    with pytest.raises(ValueError, match="distinct"):
        Choice((1, 1))
    assert Int(1, 4).bounds() == (1, 4)
    assert Choice(((16, 32, 32), True, "all")).labels() == ("16-32-32", True, "all")


def test_run_config_applies_budget_and_baselines() -> None:
    s = spec(batches=123)
    cfg = s.run_config({"selection.alpha": 0.7, "bc.network.channels": "8-16-16"}, num_threads=1)
    assert cfg.bc.train.batches == 123 and cfg.bc.train.num_threads == 1
    base = s.baseline_config(cfg)
    assert base.selection.alpha == 0.0 and base.selection.rest == "all"
    assert base.bc == cfg.bc  # same network, preprocessing and training
    default = replace(s, baseline="default").baseline_config(cfg)
    assert default.bc.network.channels == (16, 32, 32) and default.bc.train.batches == 123


def test_constraint_and_feasibility() -> None:
    assert constraint_value(5.0, 6.0) == -1.0 and is_feasible(-1.0)
    assert is_feasible(0.0) and not is_feasible(0.1) and not is_feasible(math.nan)


def _table(rows: list[dict]) -> pd.DataFrame:
    base = {"status": "done", "threshold": 5.0, "selection.alpha": 0.5, "bc.network.channels": "-"}
    recs = []
    for r in rows:
        rec = {**base, **r}
        rec["constraint"] = constraint_value(5.0, rec["safety_mean"])
        recs.append(rec)
    return trial_table(recs, PARAMS)


def test_trial_table_schema_and_nan_is_infeasible() -> None:
    t = _table(
        [
            {"trial_id": "b", "reward_mean": 10.0, "safety_mean": 6.0},
            {"trial_id": "a", "reward_mean": math.nan, "safety_mean": math.nan},
        ]
    )
    assert list(t.columns) == [*TRIAL_INFO, *PARAMS, *trial_metrics()]
    assert list(t["trial_id"]) == ["b", "a"]
    assert t["feasible"].tolist() == [True, False]
    assert t["error"].tolist() == ["", ""]


def test_winner_is_the_feasible_trial_with_the_highest_reward() -> None:
    t = _table(
        [
            {"trial_id": "unsafe_fast", "reward_mean": 900.0, "safety_mean": 4.0},
            {"trial_id": "safe_slow", "reward_mean": 300.0, "safety_mean": 9.0},
            {"trial_id": "safe_fast", "reward_mean": 600.0, "safety_mean": 5.5},
            {"trial_id": "tie_safer", "reward_mean": 600.0, "safety_mean": 7.0},
            {"trial_id": "unfinished", "reward_mean": math.nan, "safety_mean": math.nan},
        ]
    )
    w = choose_winner(t)
    assert w is not None and w.feasible and w.trial_id == "tie_safer"
    assert "3/4 feasible" in w.message
    assert w.row["reward_mean"] == 600.0
    # Tune's get_best_result would pick the unconstrained optimum instead
    assert t.loc[t["reward_mean"].idxmax(), "trial_id"] == "unsafe_fast"


def test_no_feasible_trial_gives_the_closest_one_and_says_so() -> None:
    t = _table(
        [
            {"trial_id": "far", "reward_mean": 900.0, "safety_mean": 1.0},
            {"trial_id": "close_low", "reward_mean": 100.0, "safety_mean": 4.5},
            {"trial_id": "close_high", "reward_mean": 200.0, "safety_mean": 4.5},
        ]
    )
    w = choose_winner(t)
    assert w is not None and not w.feasible and w.trial_id == "close_high"
    assert w.message.startswith("no feasible trial") and "violation 0.50" in w.message
    assert choose_winner(t.iloc[:0]) is None
    nothing = _table([{"trial_id": "x", "reward_mean": math.nan, "safety_mean": math.nan}])
    assert choose_winner(nothing) is None


def test_pareto_mask_summary_and_figure(tmp_path: Path) -> None:
    assert pareto_mask(np.array([1.0, np.nan, 2.0]), np.array([2.0, 9.0, 2.0])).tolist() == [
        False,
        False,
        True,
    ]
    t = _table(
        [
            {"trial_id": "a", "reward_mean": 100.0, "safety_mean": 7.0},
            {"trial_id": "b", "reward_mean": 500.0, "safety_mean": 3.0},
            {"trial_id": "c", "reward_mean": math.nan, "safety_mean": math.nan},
        ]
    )
    text = summary_lines(t, PARAMS)
    assert text.splitlines()[1].split()[0] == "a"  # feasible first
    path = plot_pareto(t, 5.0, tmp_path / "p" / "pareto.png", winner="a", title="t")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    import matplotlib.pyplot as plt

    labels = []
    real_save = plt.Figure.savefig

    def grab(fig, *args, **kwargs):  # the legend says what the final phase decided
        labels.extend(t.get_text() for t in fig.legends[0].get_texts())
        return real_save(fig, *args, **kwargs)

    plt.Figure.savefig = grab
    try:
        plot_pareto(t, 5.0, tmp_path / "q.png", candidates=["a", "b"])
    finally:
        plt.Figure.savefig = real_save
    assert "final-phase candidates (2)" in labels
    assert not any("winner" in x for x in labels)  # no verdict, no star

    axes: list[str] = []

    def grab_axes(fig, *args, **kwargs):  # the axes say what the search maximised, in task words
        axes.extend([fig.axes[0].get_xlabel(), fig.axes[0].get_ylabel()])
        return real_save(fig, *args, **kwargs)

    from safe_bc.study.plan import safety_axis_label
    from safe_bc.tasks import task_defaults

    t["reward_lcb"] = t["reward_mean"] - 10.0
    plt.Figure.savefig = grab_axes
    try:
        rehab = safety_axis_label(task_defaults("rehab").env.env_id)
        plot_pareto(t, 5.0, tmp_path / "r.png", objective="reward_lcb", safety_label=rehab)
    finally:
        plt.Figure.savefig = real_save
    assert axes == [
        "safety mean (each step's smallest margin: HRR fraction, model units, 100 mmHg; "
        "higher is safer)",
        "reward_lcb: the reward's one-sided lower\nconfidence bound (the objective)",
    ]
    assert "px to the grass" in safety_axis_label("CarRacing-v3")


def test_load_study_files(tmp_path: Path) -> None:
    default = load_study(REPO / "tune_jobs" / "default.py")
    assert default.name == "default" and default.trials >= 16 and default.batches == 2000
    # issue "Safety that holds": >= 10 tracks per trial, screened first; top 3 retrained with
    # 3 seeds on >= 50 fresh tracks; no step beyond d_s tolerated
    assert default.eval_episodes >= 10 and default.screens
    assert default.final_candidates == 3 and default.final_train_seeds == 3
    assert default.final_tracks_per_seed() * default.final_train_seeds >= 50
    assert default.violation_tolerance == 0.0 and default.final_workers is None
    for key in (
        "selection.eps",
        "selection.alpha",
        "selection.rest",
        "bc.network.channels",
        "bc.network.hidden",
        "bc.train.lr",
        "bc.train.batch_size",
    ):
        assert key in default.space, key
    # the observation is the measured default (results/ablation/observation), not searched
    assert not any(key.startswith("bc.preprocess.") for key in default.space)
    assert default.threshold is None and default.rollout_workers == 0
    assert default.eval_seed != default.final_seed
    smoke = load_study(REPO / "tune_jobs" / "smoke.py")
    assert smoke.trials <= 4 and smoke.batches <= 100 and smoke.max_steps is not None

    with pytest.raises(FileNotFoundError):
        load_study(tmp_path / "missing.py")
    (tmp_path / "empty.py").write_text("X = 1\n")
    with pytest.raises(ValueError, match="must define STUDY"):
        load_study(tmp_path / "empty.py")
    (tmp_path / "wrong.py").write_text("STUDY = {'name': 'x'}\n")
    with pytest.raises(ValueError, match="found dict"):
        load_study(tmp_path / "wrong.py")
    assert "safe_bc_tune_jobs_default" in sys.modules


def test_spec_summary_is_json_able() -> None:
    import json

    s = load_study(REPO / "tune_jobs" / "default.py")
    d = json.loads(json.dumps(s.summary(), default=str))
    assert d["space"]["bc.network.channels"]["options"] == ["8-16-16", "16-32-32"]
    assert d["space"]["bc.train.lr"] == {"type": "Float", "low": 1e-4, "high": 3e-3, "log": True}
    assert d["threshold"] is None and d["base"]["bc"]["train"]["seed"] == 0


def test_constraints_cover_safety_per_dimension_and_violations() -> None:
    from safe_bc.study.spec import ConstraintBars, constraints

    lim = ConstraintBars(6.0, {"left": 7.0, "right": 7.0}, 0.0, "per_dim")
    ok = {"safety_mean": 6.5, "safety_left_mean": 7.2, "safety_right_mean": 7.1}
    c = constraints({**ok, "violation_rate": 0.0}, lim)
    assert c["constraint"] <= 0 and c["constraint_safety"] == pytest.approx(-0.1)
    # one dimension below its expert mean breaks the per-dimension constraint only
    low_left = {**ok, "safety_left_mean": 6.9, "violation_rate": 0.0}
    assert constraints(low_left, lim)["constraint_safety"] == pytest.approx(0.1)
    assert constraints(low_left, replace(lim, safety_constraint="combined"))["constraint"] <= 0
    # any step beyond d_s breaks the violation constraint at tolerance 0
    c = constraints({**ok, "violation_rate": 0.001}, lim)
    assert c["constraint_violation"] == pytest.approx(0.001) and c["constraint"] > 0
    assert (
        constraints({**ok, "violation_rate": 0.001}, replace(lim, violation_tolerance=0.01))[
            "constraint"
        ]
        <= 0
    )
    assert np.isnan(constraints({"safety_mean": 7.0}, lim)["constraint"])


def test_candidates_are_fully_evaluated_feasible_first() -> None:
    from safe_bc.study.spec import choose_candidates

    t = pd.DataFrame(
        {
            "trial_id": list("abcde"),
            "status": ["done", "done", "stopped", "done", "done"],
            "reward_mean": [900.0, 950.0, 990.0, 800.0, 970.0],
            "safety_mean": [7.0] * 5,
            "constraint": [-0.1, -0.2, -1.0, 0.3, 0.1],
        }
    )
    assert choose_candidates(t, 3)["trial_id"].tolist() == ["b", "a", "e"]
    assert choose_candidates(t, 1)["trial_id"].tolist() == ["b"]


@pytest.mark.parametrize(
    ("space", "problem"),
    [
        ({"bc.train.batch_size": Float(16.0, 64.0)}, "is a Float, but the field is an int"),
        ({"bc.train.lr": Choice(("1e-3", "3e-3"))}, "the field is a float"),
        ({"bc.network.channels": Float(1.0, 2.0)}, "Choice of tuples"),
        ({"selection.rest": Choice((1, 2))}, "Choice of strings"),
        ({"bc.preprocess.grayscale": Int(0, 1)}, "Choice((False, True))"),
    ],
)
def test_a_space_of_the_wrong_type_for_its_field_is_one_line_before_ray(
    space, problem, tmp_path: Path, capsys, monkeypatch
) -> None:
    with pytest.raises(ValueError, match=re.escape(problem)):
        StudySpec("s", space)
    import ray

    def no_ray(*a, **k):
        raise AssertionError("Ray touched before the space was checked")

    # Ray's own functions, not a name some module has already imported (or would import
    # now, keeping the stand-in after this test)
    monkeypatch.setattr(ray, "init", no_ray)
    monkeypatch.setattr(ray, "is_initialized", no_ray)
    ((name, param),) = space.items()
    study = tmp_path / "bad.py"
    study.write_text(
        "from safe_bc.study.spec import Choice, Float, Int, StudySpec\n"
        f"STUDY = StudySpec('s', {{{name!r}: {param!r}}})\n"
    )
    from safe_bc.cli.commands import main

    assert main(["tune", str(study), "--results", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and problem in err[0] and not (tmp_path / "r").exists()


def test_concurrency_follows_the_cluster_capped_by_the_batch_and_max_concurrent() -> None:
    """How many trials run at once: the CPUs that fit a trial (its process and rollout
    workers), at most the batch, max_concurrent and the trials; never fewer than 1."""
    s = spec(trials=16, batch_size=8, max_concurrent=None)
    assert [s.concurrency(c) for c in (0.5, 1, 2, 7.9, 16, 64)] == [1, 1, 2, 7, 8, 8]
    assert replace(s, batch_size=None).concurrency(64) == 16  # the trials
    assert replace(s, max_concurrent=3).concurrency(16) == 3
    assert replace(s, cpus_per_trial=0.5).concurrency(2) == 4
    workers = replace(s, rollout_workers=1, cpus_per_worker=1.0)
    assert workers.trial_cpus == 2.0 and workers.concurrency(16) == 8
    assert workers.concurrency(6) == 3
    default = load_study(REPO / "tune_jobs" / "default.py")
    assert (default.concurrency(2), default.concurrency(16)) == (2, 8)  # batches of 8


def test_a_study_takes_its_tasks_eps_unless_told_and_keeps_carracings_summary() -> None:
    from safe_bc.selection import DEFAULT_EPS, SelectionConfig
    from safe_bc.tasks import task_defaults

    rehab = task_defaults("rehab")
    spec = StudySpec("mine", {"selection.alpha": Float(0.0, 1.0)}, env=rehab.env)
    assert spec.base.selection.eps == spec.critical_eps == rehab.eps
    based = StudySpec("mine", {}, env=rehab.env, base=RunConfig(), critical_eps=0.3)
    assert based.base.selection.eps == rehab.eps and based.critical_eps == 0.3
    told = StudySpec("mine", {}, env=rehab.env, base=RunConfig(SelectionConfig(eps=0.2)))
    assert told.base.selection.eps == 0.2 and told.critical_eps == rehab.eps
    car = StudySpec("car", {})  # CarRacing's eps is 2 px, as the summary always recorded
    assert car.base == RunConfig(SelectionConfig(eps=DEFAULT_EPS))
    assert car.critical_eps == task_defaults("carracing").eps == DEFAULT_EPS


def test_a_study_takes_its_tasks_handover_unless_told() -> None:
    """``StudySpec.handover`` left at its default is the task's (``TaskSpec.handover``; none
    for a task without one); ``None`` is agents alone; ``--set handover=...`` sets either."""
    from safe_bc.handover import HandoverConfig
    from safe_bc.overrides import apply_overrides, parse_override
    from safe_bc.tasks import task_defaults

    rehab, car = task_defaults("rehab"), task_defaults("carracing")
    spec = StudySpec("r", {}, env=rehab.env)
    assert spec.handover == rehab.handover and spec.handover.fallback == "safest"
    assert StudySpec("c", {}).handover == car.handover != rehab.handover
    assert StudySpec("c", {}, handover=None).handover is None
    assert StudySpec("c", {}, handover=HandoverConfig(1.0)).handover == HandoverConfig(1.0)
    alone = apply_overrides(spec, [parse_override(StudySpec, "handover=none")])
    assert alone.handover is None and spec.summary()["handover"] == rehab.handover.to_dict()
    back = apply_overrides(alone, [parse_override(StudySpec, "handover=task")])
    assert back.handover == rehab.handover
    wider = apply_overrides(spec, [parse_override(StudySpec, "handover.width=0.3")])
    assert wider.handover.width == 0.3 and wider.handover.widths == rehab.handover.widths


def test_a_study_whose_eps_makes_t_eps_everything_says_so(rehab_demos) -> None:
    from safe_bc.data.store import load_demonstrations
    from safe_bc.selection import SelectionConfig
    from safe_bc.study.spec import subset_warnings
    from safe_bc.tasks import task_defaults

    demos = load_demonstrations(rehab_demos)
    rehab = task_defaults("rehab")
    assert subset_warnings(StudySpec("ok", {}, env=rehab.env), demos) == []
    wide = StudySpec("wide", {}, env=rehab.env, base=RunConfig(SelectionConfig(eps=2.0)))
    (line,) = subset_warnings(wide, demos)
    assert line.startswith("wide: selection.eps = 2: T_eps holds every scored row")
    searched = StudySpec("s", {"selection.eps": Float(0.01, 5.0)}, env=rehab.env)
    (line,) = subset_warnings(searched, demos)
    assert "the searched selection.eps = 5" in line and "alpha has no effect" in line
