"""Hard faults of a study: the ``safe-bc tune`` driver SIGKILLed mid-study and run again, and
the Ray-private attributes the study relies on, checked against the pinned Ray."""

from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import pandas as pd
import pytest
from optuna.trial import TrialState

from safe_bc.data.store import read_table
from safe_bc.study.search import (
    PRIVATE_API,
    ConstrainedOptunaSearch,
    SpaceSampler,
    check_private_api,
)
from safe_bc.study.spec import Float
from tests.conftest import TINY_COLLECT, tiny_collect

REPO = Path(__file__).resolve().parents[2]
SMOKE = REPO / "tune_jobs" / "smoke.py"


def test_private_api_of_the_pinned_ray_is_there_and_a_missing_attribute_is_named() -> None:
    s = ConstrainedOptunaSearch(
        space=SpaceSampler({"a": Float(0.0, 1.0)}), metric="reward_mean", mode="max"
    )
    s.suggest("t1")  # set up: the Optuna study exists and the trial is tracked
    check_private_api(s)
    for attr in PRIVATE_API:
        broken = ConstrainedOptunaSearch(
            space=SpaceSampler({"a": Float(0.0, 1.0)}), metric="reward_mean", mode="max"
        )
        broken.suggest("t1")
        delattr(broken, attr)
        with pytest.raises(RuntimeError, match=attr):
            check_private_api(broken)


def test_experiment_state_persistence_hooks_of_the_pinned_ray_are_there() -> None:
    from safe_bc.study.run import check_persistence_api

    check_persistence_api()


def test_a_trial_end_forces_the_save_at_the_end_of_tunes_step() -> None:
    from ray.tune.execution.experiment_state import _ExperimentCheckpointManager
    from ray.tune.schedulers import AsyncHyperBandScheduler, TrialScheduler

    from safe_bc.study.run import SaveOnTrialEnd

    manager = _ExperimentCheckpointManager(storage=None, checkpoint_period="auto")
    controller = SimpleNamespace(_checkpoint_manager=manager)
    inner = AsyncHyperBandScheduler(time_attr="r", metric="m", mode="max", max_t=2)
    s = SaveOnTrialEnd(inner)
    assert s.metric == "m" and s.supports_buffered_results == inner.supports_buffered_results
    assert s.set_search_properties("m", "max") == inner.set_search_properties("m", "max")
    trial = SimpleNamespace(trial_id="t1")
    s.on_trial_add(controller, trial)
    assert s.on_trial_result(controller, trial, {"r": 1, "m": 1.0}) == TrialScheduler.CONTINUE
    assert not manager._should_force_sync_up
    s.on_trial_complete(controller, trial, {"r": 2, "m": 1.0})
    assert manager._should_force_sync_up
    # the forced save waits for its own copy to the storage (a plain one does not)
    waits = []
    manager._storage = SimpleNamespace(
        experiment_driver_staging_path="/staging",
        experiment_fs_path="/storage",
        syncer=SimpleNamespace(sync_up=lambda *a, **kw: True, wait=lambda: waits.append(1)),
    )
    manager.sync_up_experiment_state(save_fn=lambda: None)
    assert len(waits) == 2 and not manager._should_force_sync_up  # the previous copy, its own
    manager._last_save_time = -1e9
    waits.clear()
    manager.sync_up_experiment_state(save_fn=lambda: None, force=False)
    assert waits == []
    manager._should_force_sync_up = False
    s.on_trial_add(controller, SimpleNamespace(trial_id="t2"))
    s.on_trial_error(SimpleNamespace(_tune_controller=controller), SimpleNamespace(trial_id="t2"))
    assert manager._should_force_sync_up


def test_history_keeps_the_trials_tune_knows_and_names_the_lost_ones(tmp_path: Path) -> None:
    from safe_bc.study.run import (
        HistoryRecorder,
        _remove_orphan_trial_dirs,
        _study_history,
        read_history,
    )

    path = tmp_path / "history.jsonl"
    rec = HistoryRecorder(str(path))
    a, b, lost = (SimpleNamespace(trial_id=t) for t in ("a", "b", "x"))
    rec.on_trial_result(0, [], a, {"phase": "trained", "config": {"p": 1}})
    rec.on_trial_result(0, [], lost, {"phase": "trained"})
    rec.on_trial_result(0, [], a, {"phase": "evaluated"})
    rec.on_trial_complete(0, [], a)
    assert [r.get("event") for r in _history_rows(path)] == [None] * 3  # not before the save
    rec.on_step_end(0, [])
    rec.on_trial_result(0, [], b, {"phase": "trained"})
    rec.on_step_end(0, [])
    with open(path, "a") as f:
        f.write('{"trial_id": "b", "pha')  # cut short by a kill
    rows = _history_rows(path)
    assert [r.get("event") for r in rows] == [None, None, None, "complete", None]
    history = read_history(path)
    assert list(history["phase"]) == ["trained", "trained", "evaluated", "trained"]
    assert "config/p" not in history and "event" not in history

    trials = pd.DataFrame({"trial_id": ["a", "b"]})
    kept, names = _study_history(history, trials)
    assert list(kept["trial_id"]) == ["a", "a", "b"] and names == ["x"]
    assert _study_history(pd.DataFrame(), trials)[1] == []
    arrived = pd.DataFrame(  # concurrent trials' reports, in the order they arrived
        {"trial_id": ["b", "a", "b", "a"], "training_iteration": [1, 1, 2, 2],
         "phase": ["trained", "trained", "evaluated", "evaluated"]}
    )  # fmt: skip
    numbered = pd.DataFrame({"trial_id": ["b", "a"], "trial_number": [1, 0]})
    kept, _ = _study_history(arrived, numbered)
    assert list(zip(kept["trial_id"], kept["phase"], strict=True)) == [
        ("a", "trained"),
        ("a", "evaluated"),
        ("b", "trained"),
        ("b", "evaluated"),
    ]  # trial order, each trial's reports in its order: the same study, the same table

    exp = tmp_path / "exp"
    for name in ("trial_a", "trial_b", "trial_x", "trial_y", "other"):
        (exp / name / "checkpoint_000000").mkdir(parents=True)
    (exp / "trial_z.json").write_text("{}")
    assert _remove_orphan_trial_dirs(str(exp), {"a", "b"}) == ["x", "y"]
    assert sorted(p.name for p in exp.iterdir()) == ["other", "trial_a", "trial_b", "trial_z.json"]


# --- SIGKILL of the driver ----------------------------------------------------------------------


def _session_pids(sid: int) -> list[int]:
    """Processes of session ``sid`` (the driver started with ``start_new_session``; Ray's own
    processes run in sessions of their own and die with the driver: tests/distributed/
    test_signals.py finds them by an environment marker)."""
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            fields = stat.rsplit(")", 1)[1].split()  # after "pid (comm)": state ppid pgrp sid
            if int(fields[3]) == sid and fields[0] != "Z":  # zombies are only unreaped
                pids.append(int(entry.name))
    return pids


def _kill_session(sid: int) -> None:
    """SIGKILL the driver's process group, then any process of its session left, by pid."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(sid, signal.SIGKILL)
    deadline = time.monotonic() + 30
    while (left := _session_pids(sid)) and time.monotonic() < deadline:
        for pid in left:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        time.sleep(0.5)
    assert not _session_pids(sid), "Ray processes of the killed driver survived"


def _history_rows(path: Path) -> list[dict]:
    if not path.exists():
        return []
    rows = []
    for line in path.read_text().splitlines():
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:  # a line being written
            break
    return rows


def _evaluated(rows: list[dict]) -> set[str]:
    """Trials that have reported their full evaluation."""
    return {r["trial_id"] for r in rows if r.get("phase") == "evaluated"}


def _ended(rows: list[dict]) -> set[str]:
    """Trials whose end Tune has saved (HistoryRecorder writes the event after the save)."""
    return {r["trial_id"] for r in rows if r.get("event") == "complete"}


@pytest.mark.slow
def test_sigkilled_driver_loses_at_most_the_trials_in_flight(
    tiny_demos: Path, tmp_path: Path
) -> None:
    study_file = tmp_path / "tiny.py"
    study_file.write_text(
        "from dataclasses import replace\n"
        "from pathlib import Path\n"
        "from safe_bc.study.spec import load_study\n"
        "from safe_bc.rollout.collect import CollectConfig\n"
        f"STUDY = replace(load_study({str(SMOKE)!r}), demos=Path({str(tiny_demos)!r}),\n"
        f"    collect={TINY_COLLECT},\n"
        f"    results=Path({str(tmp_path / 'results')!r}), storage={str(tmp_path / 'ray')!r},\n"
        "    trials=6, max_concurrent=2, cpus_per_trial=1.0, batches=30, max_steps=80,\n"
        "    final_episodes=1, final_workers=0)\n"
    )
    command = [sys.executable, "-m", "safe_bc.cli.commands", "tune", str(study_file)]
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    env["RAY_AUTH_MODE"] = "disabled"
    out = tmp_path / "results" / "smoke"
    log = tmp_path / "first.log"
    with open(log, "w") as sink:
        driver = subprocess.Popen(
            command, cwd=REPO, env=env, stdout=sink, stderr=subprocess.STDOUT,
            start_new_session=True,
        )  # fmt: skip
        try:
            deadline = time.monotonic() + 400
            # the kill once two trials have logged "evaluated" (a
            # trial's end may not be saved yet: it runs again, from its stored rounds)
            while len(_evaluated(rows := _history_rows(out / "history.jsonl"))) < 2:
                assert driver.poll() is None, log.read_text()[-3000:]
                assert time.monotonic() < deadline, "no two trials evaluated in time"
                time.sleep(0.1)
            finished = _ended(rows)
            assert driver.poll() is None, "the study ended before the kill"
        finally:
            _kill_session(driver.pid)
            driver.wait()

    rerun = subprocess.run(command, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert rerun.returncode == 0, rerun.stdout[-3000:] + rerun.stderr[-3000:]
    assert "resuming study" in rerun.stdout

    trials, meta = read_table(out / "trials.parquet")
    history, hmeta = read_table(out / "history.parquet")
    assert meta["complete"] and len(trials) == 6 and trials["trial_id"].is_unique
    assert trials["status"].isin(["done", "stopped"]).all()
    # the finished trials were neither retrained nor re-evaluated
    phases = history.groupby("trial_id", sort=False)["phase"].apply(list).to_dict()
    assert finished <= set(trials["trial_id"])
    status = trials.set_index("trial_id")["status"]
    for tid in finished:
        want = ["trained", "screened"] + (["evaluated"] if status[tid] == "done" else [])
        assert phases[tid] == want, (tid, phases[tid])
    # no trial Tune knows trained twice (a trained trial resumes from its checkpoint), and none
    # has a round twice (a restarted trial reports its stored rounds)
    assert all(p.count("trained") == 1 for p in phases.values()), phases
    assert all(len(p) == len(set(p)) for p in phases.values()), phases
    # trials.parquet and history.parquet agree: the same trials, each trial's last report
    assert set(history["trial_id"]) == set(trials["trial_id"])
    last = history.groupby("trial_id").tail(1).set_index("trial_id")
    for row in trials.itertuples():
        assert last.loc[row.trial_id, "phase"] == row.phase
        a, b = last.loc[row.trial_id, "reward_mean"], row.reward_mean
        assert (math.isnan(a) and math.isnan(b)) or a == pytest.approx(b)
    # trials the restored experiment did not know are listed, not mixed into the tables
    raw = {r["trial_id"] for r in _history_rows(out / "history.jsonl") if "event" not in r}
    assert sorted(raw - set(trials["trial_id"])) == meta["lost_trials"] == hmeta["lost_trials"]
    assert not finished & set(meta["lost_trials"])
    # no orphan trial folders; the searcher holds exactly the study's trials
    exp = Path(meta["experiment_path"])
    folders = {p.name.removeprefix("trial_") for p in exp.glob("trial_*")}
    assert folders == set(trials["trial_id"])
    from safe_bc.study.run import load_searcher

    searcher = load_searcher(exp)
    assert set(searcher.constraints_by_trial()) == set(trials["trial_id"])
    states = [t.state for t in searcher.study.get_trials(deepcopy=False)]
    assert states == [TrialState.COMPLETE] * 6
    assert (out / "best.json").exists()


# --- a trial restarted after its last report ----------------------------------------------------


def crash_after_evaluation(config: dict, job, marker: str, log: str) -> None:
    """``run_trial`` that counts its evaluations (one line per call in ``log``) and, the first
    time in the study, dies after its last report (as when the driver is killed before Tune has
    saved that the trial ended: the trial runs again)."""
    import safe_bc.study.trial as mod

    original = mod.evaluate_source

    def counted(*args, **kwargs):
        with open(log, "a") as f:
            f.write(f"{args[3]}\n")
        return original(*args, **kwargs)

    mod.evaluate_source = counted
    try:
        mod.run_trial(config, job)
    finally:
        mod.evaluate_source = original
    if not os.path.exists(marker):
        Path(marker).touch()
        raise RuntimeError("injected death after the evaluated report")


def test_a_trial_run_again_after_its_evaluation_reports_it_without_evaluating_again(
    tiny_demos: Path, tmp_path: Path
) -> None:
    import functools
    from dataclasses import replace

    from safe_bc.study.run import run_study
    from safe_bc.study.spec import load_study

    spec = replace(
        load_study(SMOKE), demos=tiny_demos, collect=tiny_collect(), storage=str(tmp_path / "ray"),
        results=tmp_path / "results", batches=30, max_steps=80, final_episodes=1,
        final_workers=0, trials=1, max_concurrent=1, max_failures=1,
    )  # fmt: skip
    log = tmp_path / "evaluations.log"
    trial_fn = functools.partial(
        crash_after_evaluation, marker=str(tmp_path / "died"), log=str(log)
    )
    outcome = run_study(spec, progress=False, trial_fn=trial_fn)
    assert (tmp_path / "died").exists() and outcome.complete and outcome.errors == 0
    rounds = log.read_text().split()
    assert len(rounds) == len(set(rounds)) == (2 if spec.screens else 1), rounds
    history, _ = read_table(outcome.out / "history.parquet")
    assert history.groupby("phase").size().max() == 1, history[["trial_id", "phase"]]


# --- the final phase resumes; a finished study's rerun does no work -----------------------------


def test_final_phase_resumes_per_agent_and_evaluation_and_a_finished_study_only_reprints(
    tiny_demos: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    from dataclasses import replace

    from safe_bc.study.final_store import STORE
    from safe_bc.study.run import FINISHED, format_outcome, run_study
    from safe_bc.study.spec import load_study

    spec = replace(
        load_study(SMOKE), demos=tiny_demos, collect=tiny_collect(), storage=str(tmp_path / "ray"),
        results=tmp_path / "results", batches=30, max_steps=60, trials=2, final_candidates=1,
        final_episodes=2, final_train_seeds=2, final_workers=0, screen_episodes=0,
    )  # fmt: skip
    import safe_bc.study.final as final_mod
    from safe_bc.study.stop import StudyStopped

    evaluate_policies = final_mod.evaluate_policies

    def ctrl_c(*args, **kw):  # Ctrl-C once the final phase's agents are trained
        signal.raise_signal(signal.SIGINT)
        return evaluate_policies(*args, **kw)

    with monkeypatch.context() as m:
        m.setattr(final_mod, "evaluate_policies", ctrl_c)
        with pytest.raises(StudyStopped) as stopped:
            run_study(spec, progress=False)
    assert stopped.value.exit_code == 130 and "rerun the same command" in str(stopped.value)
    out = spec.results / spec.name
    assert not (out / "final.parquet").exists() and not (out / FINISHED).exists()
    assert len(list((out / STORE / "agents").iterdir())) == 3  # kept for the rerun
    assert len(list((out / STORE / "episodes").iterdir())) == 3  # the first seed's block

    calls: dict[str, list] = {"train": [], "evaluate": []}
    train_run = final_mod.train_run

    def counted_train(demos, run, **kw):
        calls["train"].append(run.bc.train.seed)
        return train_run(demos, run, **kw)

    def counted_evaluate(sources, *args, **kw):
        calls["evaluate"].append(sorted(sources))
        return evaluate_policies(sources, *args, **kw)

    monkeypatch.setattr(final_mod, "train_run", counted_train)
    monkeypatch.setattr(final_mod, "evaluate_policies", counted_evaluate)
    first = run_study(spec, progress=False)
    assert first.complete and first.final is not None
    assert first.exit_code == (0 if first.final.feasible else 3)  # finished, certified or not
    # no agent retrained; the evaluation under way at the Ctrl-C finished and was kept
    assert calls["train"] == [] and len(calls["evaluate"]) == 1, calls
    assert all(name.endswith("=1") for name in calls["evaluate"][0]), calls
    calls = {"train": [], "evaluate": []}
    episodes, _ = read_table(out / "final_episodes.parquet")
    first_history, _ = read_table(out / "history.parquet")
    store = out / STORE
    agents = sorted((store / "agents").iterdir())
    evaluations = sorted((store / "episodes").iterdir())
    assert len(agents) == 3  # the candidate's second seed, plain BC's two seeds
    assert len(evaluations) == 6  # (candidate, plain BC) x 2 seeds + the expert per block

    # a finished study: the rerun reads its result back and does nothing else
    capsys.readouterr()
    again = run_study(spec, progress=False)
    assert "finished before" in capsys.readouterr().out
    assert calls == {"train": [], "evaluate": []}
    assert format_outcome(again, spec.params) == format_outcome(first, spec.params)
    (out / "optuna.db").unlink()  # the copy for Optuna's tools is written again from Tune's
    run_study(spec, progress=False)
    from safe_bc.study.search import optuna_copy_problem

    assert optuna_copy_problem(out / "optuna.db", spec.name, spec.trials) == ""
    (out / "optuna.db").write_bytes(b"SQLite format 3\0" + b"\0" * 100)  # cut short
    with pytest.raises(ValueError, match=r"optuna\.db: .*rerun the same command"):
        run_study(spec, progress=False)
    (out / "optuna.db").unlink()

    # a damaged table or agent of a finished study is named in one line, never taken as
    # finished; the rerun that the line asks for writes it again
    weights = sorted((out / "recommender").glob("seed_*"))[0] / "weights.pt"
    for damaged in (out / "history.parquet", weights):
        whole = damaged.read_bytes()
        damaged.write_bytes(b"")
        with pytest.raises(ValueError, match=f"{damaged}.*delete {out / FINISHED} and rerun"):
            run_study(spec, progress=False)
        damaged.write_bytes(whole)

    # killed in the final phase: one agent and one evaluation not finished yet
    (out / FINISHED).unlink()
    (out / "final.parquet").unlink()
    import shutil

    shutil.rmtree(agents[0])
    evaluations[0].unlink()
    for damaged in (out / "history.parquet", weights):
        damaged.write_bytes(b"")
    resumed = run_study(spec, progress=False)
    from safe_bc import load_recommender

    load_recommender(out / "recommender", allow_uncertified=True)  # written again
    pd.testing.assert_frame_equal(read_table(out / "history.parquet")[0], first_history)
    assert len(calls["train"]) == 1, calls
    assert len(calls["evaluate"]) == 1 and len(calls["evaluate"][0]) == 1, calls
    again, _ = read_table(out / "final_episodes.parquet")
    pd.testing.assert_frame_equal(again, episodes)
    pd.testing.assert_frame_equal(resumed.final.table, first.final.table)
    assert (out / FINISHED).exists()


# --- Ctrl-C and SIGTERM --------------------------------------------------------------------------


def test_ctrl_c_and_sigterm_outside_fit_stop_the_study_with_their_exit_codes() -> None:
    from safe_bc.study.stop import StudyStopped, _stop_signals

    before = signal.getsignal(signal.SIGINT)  # SIG_IGN where the suite runs in the background
    for signum, code in ((signal.SIGINT, 130), (signal.SIGTERM, 143)):
        with _stop_signals() as stop:
            signal.signal(signal.SIGTERM, lambda *a: None)  # as ray.init replaces it
            from safe_bc.study.stop import _reinstall_signals

            _reinstall_signals()
            with pytest.raises(StudyStopped) as e:
                signal.raise_signal(signum)
            assert e.value.exit_code == code and stop.signum == signum
            assert signal.Signals(signum).name in str(e.value)
        assert signal.getsignal(signal.SIGINT) is before  # the handler it found, restored


def test_sigterm_during_fit_goes_to_tunes_handler_and_is_reported_after_it() -> None:
    from safe_bc.study.stop import _fit_stopped, _stop_signals

    with _stop_signals() as stop:
        ours = signal.getsignal(signal.SIGINT)
        caught = []

        def tune_handler(signum, frame):  # like Ray Tune's: note it, put the old one back
            caught.append(signum)
            signal.signal(signal.SIGINT, ours)

        signal.signal(signal.SIGINT, tune_handler)
        signal.raise_signal(signal.SIGTERM)
        assert caught == [signal.SIGINT]
        assert _fit_stopped() == signal.SIGTERM == stop.signum

    with _stop_signals() as stop:  # a fit that ended normally leaves Tune's handler behind
        signal.signal(signal.SIGINT, lambda *a: None)
        assert _fit_stopped() == 0
        assert signal.getsignal(signal.SIGINT) == stop._outside_fit  # a Ctrl-C now stops

    with _stop_signals():  # Ctrl-C caught by Tune: its handler put ours back
        assert _fit_stopped() == signal.SIGINT


def test_stopping_is_seen_in_fit_and_silences_tunes_stop_lines_and_status_table() -> None:
    import logging

    from safe_bc.study.console import StudyReporter, quiet_stop
    from safe_bc.study.stop import _stop_signals, stopping

    quiet_stop()
    quiet_stop()  # idempotent
    seen: list[str] = []

    class Keep(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            seen.append(record.getMessage().split(" ", 1)[0])

    tune_log = logging.getLogger("ray.tune.tune")
    grid_log = logging.getLogger("ray.tune.analysis.experiment_analysis")
    keep = Keep()
    for log in (tune_log, grid_log):
        log.addHandler(keep)
    reporter = StudyReporter(max_report_frequency=0)
    try:
        assert not stopping()
        with _stop_signals():
            tune_log.warning("Tune detects GPUs, but no trials are using GPUs.")
            assert not stopping() and reporter.should_report([], done=True)
            # Tune's handler caught a Ctrl-C: its notice comes first
            tune_log.warning("Stop signal received (e.g. via SIGINT/Ctrl+C), ending ...")
            assert stopping() and not reporter.should_report([], done=True)
            tune_log.error("Trials did not complete: [...]")
            grid_log.warning("Failed to fetch metrics for 2 trial(s):")
            tune_log.warning("Experiment has been interrupted, but ...")
        assert not stopping()
        with _stop_signals() as stop:
            stop.signum = signal.SIGTERM  # recorded (handed to Tune as SIGINT)
            assert stopping()
            tune_log.warning("Tune detects GPUs, but no trials are using GPUs.")
    finally:
        for log in (tune_log, grid_log):
            log.removeHandler(keep)
    assert seen == ["Tune"]


def test_a_trial_stopped_right_after_its_suggestion_has_no_config_and_still_gets_a_row() -> None:
    from safe_bc.study.run import _records

    result = SimpleNamespace(metrics=None, config=None, error=None, path=None)
    done = SimpleNamespace(
        metrics={"phase": "evaluated", "trial_id": "a", "training_iteration": 2},
        config={"p": 1, "trial_number": 0}, error=None, path="/x/trial_a",
    )  # fmt: skip
    rows = _records([done, result], ["p"])
    assert [r["status"] for r in rows] == ["done", "unfinished"]
    assert rows[1]["p"] is None


def test_exit_codes_of_an_outcome() -> None:
    from safe_bc.study.run import StudyOutcome

    base = StudyOutcome(True, pd.DataFrame(), object(), None, 0.0, Path("."), "", 0)
    assert base.exit_code == 0
    from dataclasses import replace

    assert replace(base, complete=False).exit_code == 130
    assert replace(base, stopped_by=signal.SIGTERM).exit_code == 143
    assert replace(base, errors=1).exit_code == 1
    from types import SimpleNamespace

    assert replace(base, final=SimpleNamespace(feasible=False)).exit_code == 3  # uncertified
    assert replace(base, final=SimpleNamespace(feasible=True)).exit_code == 0


# --- a full disk -------------------------------------------------------------------------------


def test_history_append_on_a_full_disk_leaves_no_half_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import errno

    from safe_bc.study.run import HistoryRecorder, read_history

    path = tmp_path / "history.jsonl"
    rec = HistoryRecorder(str(path))
    rec.on_trial_result(0, [], SimpleNamespace(trial_id="a"), {"phase": "trained"})
    before = path.read_bytes()
    real_write = os.write

    def half_then_full(fd, data):
        if len(data) > 8:
            return real_write(fd, bytes(data[: len(data) // 2]))
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "write", half_then_full)
    with pytest.raises(OSError, match="No space"):
        rec.on_trial_result(0, [], SimpleNamespace(trial_id="a"), {"phase": "screened"})
    monkeypatch.undo()
    assert path.read_bytes() == before
    assert list(read_history(path)["phase"]) == ["trained"]


class FullDisk:
    """A Tune callback whose write fails as on a full disk (Tune wraps it in a TuneError)."""

    def __new__(cls):
        from ray import tune

        class _Full(tune.Callback):
            def on_trial_result(self, iteration, trials, trial, result, **info):
                import errno

                raise OSError(errno.ENOSPC, "No space left on device", "/full/history.jsonl")

        return _Full()


def test_an_os_error_inside_tune_is_one_line_saying_what_a_rerun_does(
    tiny_demos: Path, tmp_path: Path
) -> None:
    from dataclasses import replace

    from safe_bc.study.run import run_study
    from safe_bc.study.spec import load_study

    spec = replace(
        load_study(SMOKE), demos=tiny_demos, collect=tiny_collect(), storage=str(tmp_path / "ray"),
        results=tmp_path / "results", batches=10, max_steps=40, trials=1, max_concurrent=1,
    )  # fmt: skip
    with pytest.raises(OSError) as e:
        run_study(spec, progress=False, callbacks=[FullDisk()])
    assert type(e.value) is OSError and e.value.filename == "/full/history.jsonl"
    assert "No space left" in e.value.strerror and "rerun the same command" in e.value.strerror
    assert "\n" not in str(e.value) and str(e.value).count("rerun") == 1


def test_a_finished_studys_optuna_copy_must_be_whole_and_its_own(tmp_path: Path) -> None:
    import optuna

    from safe_bc.study.plan import plan_study
    from safe_bc.study.search import check_optuna_copy
    from safe_bc.study.spec import StudySpec

    spec = StudySpec("mine", {"selection.alpha": Float(0.0, 1.0)}, trials=2, results=tmp_path)
    plan = plan_study(spec, fresh=False, command="", final=True)
    path = tmp_path / "mine" / "optuna.db"
    path.parent.mkdir()

    def make(name: str, trials: int) -> None:
        path.unlink(missing_ok=True)
        storage = optuna.storages.RDBStorage(f"sqlite:///{path}")
        study = optuna.create_study(study_name=name, storage=storage)
        for _ in range(trials):
            study.tell(study.ask({"x": optuna.distributions.FloatDistribution(0, 1)}), 1.0)
        storage.remove_session()
        storage.engine.dispose()

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    make("mine", 2)
    check_optuna_copy(plan, "")  # whole and its own
    whole = path.read_bytes()
    cases = {
        "cut short": whole[:4096],
        "damaged": b"\0" * 100 + whole[100:],
    }
    for what, data in cases.items():
        path.write_bytes(data)
        with pytest.raises(ValueError) as e:
            check_optuna_copy(plan, "")
        assert str(path) in str(e.value) and "rerun the same command" in str(e.value), what
        assert "\n" not in str(e.value)
    make("other", 2)
    with pytest.raises(ValueError, match=r"holds no study 'mine'.*not this study's"):
        check_optuna_copy(plan, "")
    make("mine", 1)
    with pytest.raises(ValueError, match="holds 1 trials of study 'mine', the study has 2"):
        check_optuna_copy(plan, "")


@pytest.mark.slow
def test_sigterm_and_ctrl_c_in_the_final_phase_stop_in_one_line_and_the_rerun_resumes(
    tiny_demos: Path, tmp_path: Path
) -> None:
    study_file = tmp_path / "tiny.py"
    study_file.write_text(
        "from dataclasses import replace\n"
        "from pathlib import Path\n"
        "from safe_bc.study.spec import load_study\n"
        "from safe_bc.rollout.collect import CollectConfig\n"
        f"STUDY = replace(load_study({str(SMOKE)!r}), demos=Path({str(tiny_demos)!r}),\n"
        f"    collect={TINY_COLLECT},\n"
        f"    results=Path({str(tmp_path / 'results')!r}), storage={str(tmp_path / 'ray')!r},\n"
        "    trials=2, max_concurrent=1, batches=30, max_steps=60, screen_episodes=0,\n"
        "    final_candidates=1, final_train_seeds=3, final_episodes=3, final_workers=0)\n"
    )
    command = [sys.executable, "-m", "safe_bc.cli.commands", "tune", str(study_file)]
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    env["RAY_AUTH_MODE"] = "disabled"
    out = tmp_path / "results" / "smoke"
    for signum, code in ((signal.SIGTERM, 143), (signal.SIGINT, 130)):
        log = tmp_path / f"{signum}.log"
        with open(log, "w") as sink:
            driver = subprocess.Popen(
                command, cwd=REPO, env=env, stdout=sink, stderr=subprocess.STDOUT,
                start_new_session=True,
            )  # fmt: skip
            try:
                deadline = time.monotonic() + 400
                while "final phase: training" not in log.read_text():
                    assert driver.poll() is None, log.read_text()[-3000:]
                    assert time.monotonic() < deadline, "the final phase did not start in time"
                    time.sleep(0.2)
                time.sleep(1.0)
                driver.send_signal(signum)  # the driver only
                assert driver.wait(timeout=120) == code, log.read_text()[-3000:]
            finally:
                _kill_session(driver.pid)
                driver.wait()
        text = log.read_text()
        assert "Traceback" not in text and "Stop signal received" not in text, text[-3000:]
        assert f"stopped by {signal.Signals(signum).name}" in text and "rerun" in text
        assert not (out / "final.parquet").exists()
    rerun = subprocess.run(command, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert rerun.returncode in (0, 1), rerun.stdout[-3000:] + rerun.stderr[-3000:]
    assert (out / "final.parquet").exists() and (out / "finished.json").exists()
    again = subprocess.run(command, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert again.returncode == rerun.returncode and "finished before" in again.stdout


def test_a_deferred_signal_stops_after_the_grace_period_and_prints_nothing(
    monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    import safe_bc.study.stop as stop_mod
    from safe_bc.study.stop import StudyStopped, _stop_signals, deferred_stop

    monkeypatch.setattr(stop_mod, "STOP_GRACE_S", 0.2)
    for signum, code in ((signal.SIGTERM, 143), (signal.SIGINT, 130)):
        t0 = time.monotonic()
        with _stop_signals(), pytest.raises(StudyStopped) as e, deferred_stop():
            signal.raise_signal(signum)
            while time.monotonic() - t0 < 10:  # work that outlasts the grace period
                time.sleep(0.01)
            pytest.fail("not stopped after the grace period")
        assert e.value.exit_code == code and time.monotonic() - t0 < 5
    # stopped at a stop point in time: the timer is cancelled and delivers nothing later
    with _stop_signals(), pytest.raises(StudyStopped), deferred_stop():
        signal.raise_signal(signal.SIGINT)
    time.sleep(0.4)
    assert capsys.readouterr() == ("", "")  # the one line is the command line's


def test_a_signal_in_a_deferred_block_stops_at_the_next_stop_point_with_its_own_code() -> None:
    from safe_bc.study.stop import StudyStopped, _stop_signals, deferred_stop, stop_point

    for signum, code in ((signal.SIGTERM, 143), (signal.SIGINT, 130)):
        with _stop_signals(), pytest.raises(StudyStopped) as e, deferred_stop():
            signal.raise_signal(signum)  # recorded, not raised here
            done = True
            stop_point()
        assert done and e.value.exit_code == code
        with _stop_signals(), pytest.raises(StudyStopped), deferred_stop():
            signal.raise_signal(signum)
            signal.raise_signal(signum)  # a second one stops at once
            pytest.fail("not stopped by the second signal")
