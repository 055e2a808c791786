"""Same study file, same trials: a batched study gives the same trial table (configurations
and metrics) at 1, 2 and 4 trials at once."""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from ray.tune.schedulers import TrialScheduler

from safe_bc.study.search import (
    NUMBER,
    ConstrainedOptunaSearch,
    SpaceSampler,
    halving_decision,
)
from safe_bc.study.spec import Float, load_study

REPO = Path(__file__).resolve().parents[2]

TIMING = ("train_seconds", "improve_seconds", "eval_seconds", "round_eval_seconds",
          "store_seconds", "duration_s", "trial_id")  # fmt: skip
"""Columns that differ between runs by nature (wall-clock, Tune's random trial ids)."""


def _searcher(batch_size: int | None, max_trials: int | None = None) -> ConstrainedOptunaSearch:
    from optuna.samplers import TPESampler

    return ConstrainedOptunaSearch(
        space=SpaceSampler({"a": Float(0.0, 1.0)}),
        metric="reward_mean",
        mode="max",
        sampler=TPESampler(seed=0, n_startup_trials=2, constant_liar=True),
        batch_size=batch_size,
        max_trials=max_trials,
    )


def _result(a: float) -> dict:
    return {"reward_mean": -((a - 0.3) ** 2), "constraint_safety": -1.0,
            "constraint_violation": 0.0, "constraint_deferral": 0.0}  # fmt: skip


def test_batched_searcher_tells_in_trial_order_and_waits_for_the_batch() -> None:
    suggestions = []
    for finish_order in ((0, 1), (1, 0)):
        s = _searcher(batch_size=2, max_trials=5)
        cfgs = {}
        for n in range(5):
            if n % 2 == 0 and n:
                first, second = (f"t{n - 2 + i}" for i in finish_order)
                assert s.suggest(f"t{n}") is None  # the batch is not in yet
                s.on_trial_complete(first, _result(cfgs[first]["a"]))
                assert s.suggest(f"t{n}") is None and s.batch_pending() == [second]
                s.on_trial_complete(second, _result(cfgs[second]["a"]))
            cfg = s.suggest(f"t{n}")
            assert cfg[NUMBER] == n
            cfgs[f"t{n}"] = cfg
        s.on_trial_complete("t4", _result(cfgs["t4"]["a"]))  # the last batch has 1 trial
        numbers = [t.number for t in s.study.get_trials(deepcopy=False)]
        assert numbers == [0, 1, 2, 3, 4]
        assert all(t.state.name == "COMPLETE" for t in s.study.get_trials(deepcopy=False))
        assert [t.user_attrs["tune_trial_id"] for t in s.study.trials] == [f"t{n}" for n in
                                                                          range(5)]  # fmt: skip
        suggestions.append([cfgs[f"t{n}"]["a"] for n in range(5)])
    assert suggestions[0] == suggestions[1]


def test_searcher_copies_its_study_to_an_optuna_storage_that_optuna_loads(tmp_path) -> None:
    import optuna

    url = f"sqlite:///{tmp_path / 'optuna.db'}"
    s = _searcher(batch_size=2, max_trials=3)
    s._export_to = url
    cfgs = {f"t{n}": s.suggest(f"t{n}") for n in range(2)}
    s.on_trial_complete("t1", _result(cfgs["t1"]["a"]))
    assert not (tmp_path / "optuna.db").exists()  # nothing told yet
    s.on_trial_complete("t0", {**_result(cfgs["t0"]["a"]), "constraint_safety": 0.5})
    s.suggest("t2")
    loaded = optuna.load_study(study_name="optuna", storage=url)
    trials = loaded.get_trials()
    assert [t.state.name for t in trials] == ["COMPLETE", "COMPLETE"]  # copied at the tell
    # named (Optuna 5) and as the list optuna-dashboard reads, in the searcher's order
    assert trials[0].constraints == {"safety": 0.5, "violations": 0.0, "deferral": 0.0,
                                     "0": 0.5, "1": 0.0, "2": 0.0}  # fmt: skip
    assert trials[1].system_attrs["constraints"] == [-1.0, 0.0, 0.0]
    assert loaded.metric_names == ["reward_mean"]
    assert s.study.trials[0].constraints == {"safety": 0.5, "violations": 0.0, "deferral": 0.0}
    assert [t.params["a"] for t in trials[:2]] == [cfgs["t0"]["a"], cfgs["t1"]["a"]]
    assert [t.user_attrs["tune_trial_id"] for t in trials] == ["t0", "t1"]
    assert loaded.user_attrs["objective"] == "reward_mean" and loaded.user_attrs["batch_size"] == 2
    s.on_trial_complete("t2", _result(0.3))  # the copy is replaced, not appended to
    trials = optuna.load_study(study_name="optuna", storage=url).get_trials()
    assert [t.state.name for t in trials] == ["COMPLETE"] * 3
    assert not list(tmp_path.glob(".*.tmp"))


def test_constraint_list_follows_the_given_names_and_leaves_other_trials_alone() -> None:
    import optuna

    from safe_bc.study.search import with_constraint_list

    named = optuna.trial.create_trial(value=1.0, constraints={"violations": 0.2, "safety": -1.0})
    out = with_constraint_list(named, ["safety", "violations"])
    assert out.system_attrs["constraints"] == [-1.0, 0.2]
    assert "constraints" not in named.system_attrs  # the original is not changed
    assert with_constraint_list(named).system_attrs["constraints"] == [-1.0, 0.2]  # sorted
    plain = optuna.trial.create_trial(value=1.0)
    assert with_constraint_list(plain, ["safety"]) is plain


def test_a_failing_copy_warns_and_the_study_goes_on() -> None:
    s = _searcher(batch_size=None)
    s._export_to = "postgresql://127.0.0.1:1/none"  # no driver, no server
    cfg = s.suggest("t0")
    with pytest.warns(UserWarning, match="could not copy the Optuna study"):
        s.on_trial_complete("t0", _result(cfg["a"]))
    assert s.study.trials[0].state.name == "COMPLETE"


def test_a_copy_to_a_full_disk_warns_in_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import sqlite3

    import sqlalchemy.exc

    import safe_bc.study.search as search

    def full(*args, **kwargs):  # what SQLAlchemy raises when SQLite finds the disk full
        raise sqlalchemy.exc.OperationalError(
            "INSERT INTO trials (number, study_id) VALUES (?, ?)",
            (0, 1),
            sqlite3.OperationalError("database or disk is full"),
        )

    monkeypatch.setattr(search, "_copy_into", full)
    s = _searcher(batch_size=None)
    s._export_to = f"sqlite:///{tmp_path / 'optuna.db'}"
    cfg = s.suggest("t0")
    with pytest.warns(UserWarning) as caught:
        s.on_trial_complete("t0", _result(cfg["a"]))
    (message,) = [str(w.message) for w in caught]
    assert "database or disk is full" in message and "\n" not in message, message
    assert not list(tmp_path.iterdir())  # no half-written copy


def test_a_studys_warnings_print_as_one_line() -> None:
    import warnings

    from safe_bc.study.console import one_line_warnings

    before = warnings.formatwarning
    message = "could not copy: (sqlite3.OperationalError) full\n  [SQL: ...]"
    with one_line_warnings():
        shown = warnings.formatwarning(message, UserWarning, "search.py", 1, "warnings.warn(x)")
    assert shown == "warning: could not copy: (sqlite3.OperationalError) full [SQL: ...]\n"
    assert warnings.formatwarning is before


def test_batch_halving_compares_with_earlier_batches_only() -> None:
    assert halving_decision(5.0, []) == TrialScheduler.CONTINUE
    assert halving_decision(5.0, [1.0, 9.0, 10.0]) == TrialScheduler.STOP
    assert halving_decision(5.0, [1.0, 2.0, float("nan")]) == TrialScheduler.CONTINUE


def _table(out: Path) -> pd.DataFrame:
    from safe_bc.data.store import read_table

    t, _ = read_table(out / "trials.parquet")
    return t.drop(columns=[c for c in TIMING if c in t]).reset_index(drop=True)


STUDY_FILE = """from dataclasses import replace
from pathlib import Path

from safe_bc.rollout.collect import CollectConfig
from safe_bc.study.spec import load_study
from safe_bc.tasks import task_defaults

STUDY = replace(
    load_study({rehab!r}), demos=Path({demos!r}), trials=8, batch_size=4, batches=20,
    collect=CollectConfig.for_task(task_defaults("rehab"), episodes=8, workers=1),
    eval_episodes=3, screen_episodes=1, startup_trials=2, final_episodes=1,
    final_candidates=1, final_train_seeds=1,
)
"""


@pytest.mark.slow
def test_same_study_same_trials_at_one_two_and_four_trials_at_once(
    ray_session, rehab_demos: Path, tmp_path: Path
) -> None:
    """Two batches of 4 (TPE and the halving of the second batch read the first): 1 at a
    time (``max_concurrent=1``), 2 at a time (``None`` resolved from the session's 2 CPUs) and
    4 at a time (``scripts.cluster_scaling --cpus 4``: its own local Ray of 4 logical CPUs
    on this machine, in a subprocess) give the same trials."""
    import subprocess
    import sys

    import optuna

    from safe_bc.study.run import run_study

    study = tmp_path / "study.py"
    study.write_text(STUDY_FILE.format(rehab=str(REPO / "tune_jobs" / "rehab.py"),
                                       demos=str(rehab_demos)))  # fmt: skip
    base = load_study(study)
    tables = []
    for concurrent in (1, None):
        spec = replace(
            base,
            max_concurrent=concurrent,
            storage=str(tmp_path / f"c{concurrent}" / "ray"),
            results=tmp_path / f"c{concurrent}" / "results",
        )
        outcome = run_study(spec, progress=False, final=False)
        assert outcome.complete and outcome.errors == 0, outcome.trials[["status", "error"]]
        timing = outcome.timing.set_index("phase")
        assert timing.loc["tuning", "count"] == (concurrent or 2)  # most running at once
        tables.append(_table(outcome.out))
        stored = optuna.load_study(
            study_name=spec.name, storage=f"sqlite:///{outcome.out / 'optuna.db'}"
        ).get_trials()
        assert [t.number for t in stored] == list(range(8))
        table = tables[-1]
        for t, row in zip(stored, table.itertuples(), strict=True):
            if row.status == "invalid":
                assert t.state.name == "FAIL"
                continue
            assert t.value == pytest.approx(row.reward_mean)
            assert t.constraints["safety"] == pytest.approx(row.constraint_safety)
            assert t.constraints["violations"] == pytest.approx(row.constraint_violation)

    out = tmp_path / "scaling.parquet"
    cmd = [sys.executable, "-m", "scripts.cluster_scaling", "--cpus", "4", "--study",
           str(study), "--batch-size", "4", "--results", str(tmp_path / "c4"), "--out",
           str(out)]  # fmt: skip
    env = {**os.environ, "PYTHONPATH": str(REPO), "RAY_AUTH_MODE": "disabled"}
    env.pop("RAY_ADDRESS", None)
    run = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    from safe_bc.data.store import read_table

    row = read_table(out)[0].iloc[0]
    assert (row["cpus"], row["trials"], row["finished"]) == (4, 8, 8)
    assert row["concurrency"] == 4 and row["concurrency_reached"] == 4  # a whole batch at once
    tables.append(_table(tmp_path / "c4" / "results" / base.name))

    one, two, four = tables
    assert one["trial_number"].tolist() == list(range(8))
    assert one["status"].isin(["done", "stopped", "invalid"]).all()
    pd.testing.assert_frame_equal(one, two)
    pd.testing.assert_frame_equal(one, four)
    assert np.isfinite(one["reward_mean"].astype(float)).any()


def test_copy_stores_screened_trials_pruned_and_marks_the_final_winner(tmp_path) -> None:
    import optuna

    from safe_bc.study.search import WINNER, export_study, mark_final_winner

    url = f"sqlite:///{tmp_path / 'optuna.db'}"
    s = _searcher(batch_size=None)
    s._export_to = url
    # t1 is stopped by the screening with the highest value; t2 is the best evaluated trial;
    # the final phase's re-evaluation picks t0
    runs = {"t0": (1.0, "evaluated"), "t1": (5.0, "screened"), "t2": (2.0, "evaluated")}
    for tid, (value, phase) in runs.items():
        s.suggest(tid)
        result = {**_result(0.3), "reward_mean": value, "phase": phase, "training_iteration": 1}
        s.on_trial_result(tid, result)
        s.on_trial_complete(tid, result)
    assert [t.state.name for t in s.study.trials] == ["COMPLETE"] * 3  # the sampler's: as told
    loaded = optuna.load_study(study_name="optuna", storage=url)
    assert [t.state.name for t in loaded.trials] == ["COMPLETE", "PRUNED", "COMPLETE"]
    pruned = loaded.trials[1]
    assert pruned.value == 5.0 and pruned.intermediate_values == {1: 5.0}
    assert pruned.constraints["safety"] == -1.0  # constraints kept
    assert loaded.best_trial.number == 2  # a pruned trial is never Optuna's best
    assert WINNER not in loaded.user_attrs

    mark_final_winner(url, "optuna", "t0", True)
    loaded = optuna.load_study(study_name="optuna", storage=url)
    assert loaded.user_attrs[WINNER] == "t0" and loaded.user_attrs["final_winner_number"] == 0
    assert loaded.user_attrs["final_winner_feasible"] is True
    assert [t.user_attrs.get(WINNER) for t in loaded.trials] == [True, None, None]
    assert loaded.best_trial.number == 2  # the trial phase's best, not the final winner
    assert [t.state.name for t in loaded.trials] == ["COMPLETE", "PRUNED", "COMPLETE"]
    assert loaded.metric_names == ["reward_mean"] and loaded.user_attrs["objective"]
    assert loaded.trials[0].system_attrs["constraints"] == [-1.0, 0.0, 0.0]

    mark_final_winner(url, "optuna", "t2", False)  # marked again: the old mark is taken off
    loaded = optuna.load_study(study_name="optuna", storage=url)
    assert [t.user_attrs.get(WINNER) for t in loaded.trials] == [None, None, True]
    assert loaded.user_attrs["final_winner_feasible"] is False
    with pytest.warns(UserWarning, match="no trial with Tune trial id 'nope'"):
        mark_final_winner(url, "optuna", "nope", True)
    assert optuna.load_study(study_name="optuna", storage=url).user_attrs[WINNER] == "t2"
    assert not list(tmp_path.glob(".*.tmp"))

    rdb = f"sqlite+pysqlite:///{tmp_path / 'rdb.db'}"  # the in-place path of other RDB URLs
    export_study(s.study, rdb, metric="reward_mean")
    mark_final_winner(rdb, "optuna", "t0", True)
    loaded = optuna.load_study(study_name="optuna", storage=rdb)
    assert [t.user_attrs.get(WINNER) for t in loaded.trials] == [True, None, None]
    assert [t.state.name for t in loaded.trials] == ["COMPLETE", "PRUNED", "COMPLETE"]
