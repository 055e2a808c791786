"""Tiny constrained studies on the shared local Ray: the CLI end to end, constraints inside
Optuna, a failed trial retried from its checkpoint, and resume after an interruption."""

from __future__ import annotations

import contextlib
import functools
import math
import os
import pickle
import signal
import sys
from dataclasses import replace
from pathlib import Path

import cloudpickle
import numpy as np
import pytest
from optuna.trial import TrialState
from ray import tune

from safe_bc.cli.commands import main
from safe_bc.data.curves import read_events, read_hparams
from safe_bc.data.store import load_demonstrations, read_meta, read_table
from safe_bc.metrics import combined
from safe_bc.seeds import VALIDATION_SEED, heldout_seeds
from safe_bc.study.plan import validation_path
from safe_bc.study.run import (
    ConstrainedOptunaSearch,
    SpaceSampler,
    TrialJob,
    load_searcher,
    read_timing_log,
    run_study,
    run_trial,
)
from safe_bc.study.search import WINNER
from safe_bc.study.spec import TRIAL_INFO, Choice, Float, load_study, trial_metrics
from safe_bc.study.timing import PHASES
from safe_bc.study.trial_curves import final_run_name, run_names
from safe_bc.tasks import task_defaults
from tests.conftest import TINY_COLLECT, tiny_collect

REPO = Path(__file__).resolve().parents[2]
SMOKE = REPO / "tune_jobs" / "smoke.py"

# The trial wrapper below runs in Ray workers, which cannot import this test module.
cloudpickle.register_pickle_by_value(sys.modules[__name__])


def small(tmp_path: Path, demos: Path, **kw):
    """The smoke study, shrunk further, writing under ``tmp_path``."""
    defaults = dict(
        demos=demos,
        collect=tiny_collect(),
        storage=str(tmp_path / "ray"),
        results=tmp_path / "results",
        batches=30,
        max_steps=80,
        final_episodes=1,
        final_workers=0,
    )
    return replace(load_study(SMOKE), **{**defaults, **kw})


def test_searcher_hands_constraints_to_optuna_and_keeps_them_in_its_checkpoint(tmp_path) -> None:
    s = ConstrainedOptunaSearch(
        space=SpaceSampler({"a": Float(0.0, 1.0), "c": Choice(((1, 2), (3, 4)))}),
        metric="reward_mean",
        mode="max",
    )
    cfg = s.suggest("t1")
    assert 0 <= cfg["a"] <= 1 and cfg["c"] in ("1-2", "3-4")
    s.suggest("t2")
    s.suggest("t3")
    s.on_trial_result("t1", {"reward_mean": math.nan, "training_iteration": 1})  # not forwarded
    both = {"constraint_safety": 0.5, "constraint_violation": 0.0, "constraint_deferral": -1.0}
    s.on_trial_complete("t1", {"reward_mean": 10.0, **both})
    s.on_trial_complete(
        "t2",
        {"reward_mean": 5.0, "constraint_safety": -1.0, "constraint_violation": 0.1,
         "constraint_deferral": 0.02},
    )  # fmt: skip
    s.on_trial_complete("t3", {"reward_mean": 7.0, "constraint_safety": -1.0})  # one missing
    trials = s.study.get_trials(deepcopy=False)
    assert [t.state for t in trials] == [TrialState.COMPLETE, TrialState.COMPLETE, TrialState.FAIL]
    assert trials[0].intermediate_values == {}
    assert trials[0].constraints == {"safety": 0.5, "violations": 0.0, "deferral": -1.0}
    assert trials[1].constraints == {"safety": -1.0, "violations": 0.1, "deferral": 0.02}
    s.save(str(tmp_path / "searcher.pkl"))
    restored = ConstrainedOptunaSearch()
    restored.restore(str(tmp_path / "searcher.pkl"))
    assert restored.constraints_by_trial() == {
        "t1": {"safety": 0.5, "violations": 0.0, "deferral": -1.0},
        "t2": {"safety": -1.0, "violations": 0.1, "deferral": 0.02},
        "t3": {},
    }
    pickle.dumps(SpaceSampler({"a": Float(0.0, 1.0)}))  # the define-by-run space pickles


def test_cli_study_end_to_end(tiny_demos: Path, tmp_path: Path, capsys) -> None:
    study_file = tmp_path / "tiny.py"
    study_file.write_text(
        "from dataclasses import replace\n"
        "from pathlib import Path\n"
        "from safe_bc.study.spec import load_study\n"
        "from safe_bc.rollout.collect import CollectConfig\n"
        f"STUDY = replace(load_study({str(SMOKE)!r}), demos=Path({str(tiny_demos)!r}),\n"
        f"    collect={TINY_COLLECT},\n"
        f"    results=Path({str(tmp_path / 'results')!r}), batches=30, max_steps=80,\n"
        "    final_episodes=1, final_workers=0, max_concurrent=2,\n"
        "    rollout_workers=1, cpus_per_trial=0.5, cpus_per_worker=0.5)\n"
    )
    storage = str(tmp_path / "ray")
    rc = main(["tune", str(study_file), "--trials", "3", "--storage", storage])
    printed = capsys.readouterr().out
    assert "final phase on fresh held-out tracks" in printed
    out = tmp_path / "results" / "smoke"
    # the tiny study's candidates may miss the constraints on 2 final episodes: then exit 3,
    # one line per candidate naming what it missed, never "the winner"
    feasible = __import__("json").loads((out / "best.json").read_text())["feasible"]
    assert rc == (0 if feasible else 3), printed
    if not feasible:
        assert "no candidate met every constraint" in printed and "candidate " in printed
    spec = load_study(study_file)

    trials, meta = read_table(out / "trials.parquet")
    assert list(trials.columns) == [*TRIAL_INFO, *spec.params, *trial_metrics()]
    assert len(trials) == 3 and trials["trial_id"].is_unique
    # screened on 1 track; successive halving may stop a trial there
    assert trials["status"].isin(["done", "stopped"]).all() and (trials["status"] == "done").any()
    done = trials[trials["status"] == "done"]
    assert (done["phase"] == "evaluated").all() and (done["episodes"] == spec.eval_episodes).all()
    stopped = trials[trials["status"] == "stopped"]
    assert (stopped["phase"] == "screened").all() and (stopped["episodes"] == 1).all()
    demos = load_demonstrations(tiny_demos)
    expert = float(combined(demos.safety[demos.scored]).mean())
    assert meta["threshold"] == pytest.approx(expert)  # default: the expert's demo safety
    assert meta["cost_limits"] == pytest.approx(list(demos.limits))
    # two constraints, each <= 0 when met; the safety one is at least the combined gap
    assert (trials["constraint_safety"] >= expert - trials["safety_mean"] - 1e-9).all()
    np.testing.assert_allclose(trials["constraint_violation"], trials["violation_rate"])
    np.testing.assert_allclose(
        trials["constraint"], trials[["constraint_safety", "constraint_violation"]].max(axis=1)
    )
    assert (trials["feasible"] == (trials["constraint"] <= 0)).all()
    seeds = heldout_seeds(spec.eval_seed, spec.eval_episodes)
    assert (trials["eval_seeds"] == ",".join(map(str, seeds))).all()
    assert (trials["steps_mean"] == 80).all() and (trials["duration_s"] > 0).all()
    assert trials["bc.network.channels"].isin(["4-8-8", "8-16-16"]).all()
    assert meta["command"].startswith("safe-bc tune") and "--trials 3" in meta["command"]
    assert meta["provenance"]["git_revision"] and meta["seeds"]["final_seed"] == spec.final_seed
    assert meta["study"]["name"] == "smoke" and meta["complete"] is True
    # the curves' validation set: collected by default beside the demonstrations, the task's
    # size, on tracks of its own, recorded with the study's inputs
    n_val = task_defaults("carracing").validation_episodes
    assert n_val >= 1 and spec.validation_episodes == n_val
    val = meta["inputs"]["validation"]
    assert val["episodes"] == n_val and val["digest"] != meta["inputs"]["demos"]["digest"]
    assert read_meta(validation_path(tiny_demos)).seed == VALIDATION_SEED

    history, hmeta = read_table(out / "history.parquet")
    assert hmeta["command"] == meta["command"]
    phases = history.groupby("trial_id")["phase"].apply(list).to_dict()
    for row in trials.itertuples():
        want = ["trained", "screened"] + (["evaluated"] if row.status == "done" else [])
        assert phases[row.trial_id] == want

    # both constraint values of every trial are inside the Optuna study
    searcher = load_searcher(meta["experiment_path"])
    held = searcher.constraints_by_trial()
    for row in trials.itertuples():
        assert held[row.trial_id]["safety"] == pytest.approx(row.constraint_safety)
        assert held[row.trial_id]["violations"] == pytest.approx(row.constraint_violation)
    states = [t.state for t in searcher.study.get_trials(deepcopy=False)]
    assert states == [TrialState.COMPLETE] * 3

    # the final phase: candidates retrained with 2 seeds on fresh tracks, winner chosen there
    best = __import__("json").loads((out / "best.json").read_text())
    final, fmeta = read_table(out / "final.parquet")
    cands = fmeta["final_design"]["candidates"]
    assert 1 <= len(cands) <= spec.final_candidates and set(cands) <= set(done["trial_id"])
    assert final["method"].tolist() == [*cands, "plain_bc", "expert"]
    assert (final.loc[final["method"] != "expert", "n_train_seeds"] == 2).all()
    assert {"reward_lo", "reward_hi", "violation_steps", "episodes_with_violation"} <= set(final)
    assert best["trial_id"] in cands and best["trial_id"] == fmeta["winner"]
    assert best["feasible"] == bool(final.set_index("method").loc[best["trial_id"], "feasible"])
    # the Optuna copy: trials stopped by the screening PRUNED, best.json's winner marked
    import optuna

    copy = optuna.load_study(study_name=spec.name, storage=f"sqlite:///{out / 'optuna.db'}")
    states = {x.user_attrs["tune_trial_id"]: x.state.name for x in copy.trials}
    assert states == {
        r.trial_id: "PRUNED" if r.status == "stopped" else "COMPLETE" for r in trials.itertuples()
    }
    assert copy.user_attrs["final_winner"] == best["trial_id"]
    marked = [x.user_attrs["tune_trial_id"] for x in copy.trials if x.user_attrs.get(WINNER)]
    assert marked == [best["trial_id"]]
    assert set(fmeta["final_design"]["env_seeds"]).isdisjoint(seeds)
    assert fmeta["configs"]["plain_bc"]["selection"]["alpha"] == 0.0
    episodes, _ = read_table(out / "final_episodes.parquet")
    per_seed = episodes[episodes["method"] == "plain_bc"].groupby("train_seed")["env_seed"]
    assert per_seed.apply(frozenset).nunique() == 2  # each seed on its own tracks
    paired, _ = read_table(out / "final_paired.parquet")  # every method vs the expert
    assert set(paired.loc[paired["vs"] == "expert", "method"]) == {*cands, "plain_bc"}
    assert (paired["n_pairs"] == len(episodes[episodes["method"] == "expert"])).all()
    assert (out / "pareto.png").stat().st_size > 0

    # where the time went: every driver phase timed, the trials' own seconds beside them
    logged = {r["phase"] for r in read_timing_log(out / "timing.jsonl")}
    assert set(PHASES) - {"other"} <= logged and {"total", "optuna_copy"} <= logged
    timing, tmeta = read_table(out / "timing.parquet")
    t = timing.set_index("phase")
    assert tmeta["provenance"]["git_revision"] and tmeta["command"] == meta["command"]
    assert set(PHASES) <= set(t.index) and (t["seconds"] >= 0).all()
    for part in ("study", "tuning slots"):
        assert t.loc[t["part_of"] == part, "share"].sum() == pytest.approx(1.0)
    for phase in ("tuning", "final_train", "final_evaluation", "trial_train", "trial_evaluation",
                  "trial_storage"):  # fmt: skip
        assert t.loc[phase, "seconds"] > 0, phase
    assert t.loc["trial_train", "seconds"] == pytest.approx(trials["train_seconds"].sum())
    assert t.loc["optuna_copy", "count"] >= 1
    assert "| phase" in (out / "timing.md").read_text() and "\ntime: " in printed
    assert (trials["store_seconds"] > 0).all()  # the checkpoint and the stored rounds
    for _, rows in history[history["phase"] != "trained"].groupby("trial_id"):
        assert rows["round_eval_seconds"].sum() == pytest.approx(rows["eval_seconds"].iloc[-1])

    # every trial's curves: its BC loss per logged batch (Parquet and TensorBoard, with the
    # validation set's loss) and Tune's TensorBoard logger's scalars per reported round
    folders = {p.parent.name: p.parent for p in (tmp_path / "ray" / "smoke").glob("*/result.json")}
    assert len(folders) == 3
    for folder in folders.values():
        curve, cmeta = read_table(folder / "bc" / "curve.parquet")
        assert curve["batch"].is_monotonic_increasing and curve["batch"].iloc[-1] == 30
        assert np.isfinite(curve["val_loss"]).all() and cmeta["train_seed"] == spec.trial_seeds()[0]
        assert set(read_events(folder / "bc")["tag"]) >= {"bc/train_loss", "bc/val_loss"}
        tune_events = read_events(folder)
        steps = tune_events.groupby("tag")["step"].apply(list)
        assert steps["ray/tune/train_loss"][:2] == [1, 2]  # trained, screened (, evaluated)
        assert steps["ray/tune/reward_mean"][0] == 2  # the first round's evaluation

    # the study's board: a run per trial named for a person (BC losses per logged batch,
    # evaluation per round, HParams entry with the winner), the final phase's agents beside
    board = out / "tensorboard"
    names = run_names(trials, spec.params)
    for row in trials.itertuples():
        run = board / names[row.trial_id]
        assert names[row.trial_id].startswith(f"t{int(row.trial_number):03d}_")
        steps = read_events(run).groupby("tag")["step"].apply(list).to_dict()
        assert steps["bc/train_loss"] == steps["bc/val_loss"] and steps["bc/val_loss"][-1] == 30
        rounds = [1, 2] if row.status == "done" else [1]
        for tag in ("reward_mean", "any_violation", "deferred_share", "constraint"):
            assert steps[f"eval/{tag}"] == rounds, tag
        hp = read_hparams(run)
        assert hp["feasible"] == bool(row.feasible) and hp["status"] == row.status
        assert hp["winner"] == (row.trial_id == best["trial_id"] and best["feasible"])
    finals = {p.name for p in board.glob("final_*")}
    first, second = spec.trial_seeds()[0], spec.trial_seeds()[0] + 1
    assert {final_run_name(c, second, names) for c in cands} <= finals
    assert {f"final_plain_bc_seed{first}", f"final_plain_bc_seed{second}"} <= finals
    for name in finals:  # the final phase's retrained agents record the validation loss too
        assert "bc/val_loss" in set(read_events(board / name)["tag"]), name

    # a finished study's rerun only reprints (the time lines too): no table is rewritten
    before = {p.name: p.stat().st_mtime_ns for p in out.iterdir() if p.is_file()}
    rc = main(["tune", str(study_file), "--trials", "3", "--storage", storage])
    again = capsys.readouterr().out
    assert rc == (0 if feasible else 3) and "finished before" in again and "\ntime: " in again
    assert {p.name: p.stat().st_mtime_ns for p in out.iterdir() if p.is_file()} == before


class InterruptOnce(tune.Callback):
    """Ctrl-C (SIGINT) after the first finished trial, once (the callback is restored too)."""

    def __init__(self, marker: str) -> None:
        self.marker = marker

    def on_trial_complete(self, iteration, trials, trial, **info) -> None:
        if not os.path.exists(self.marker):
            Path(self.marker).touch()
            signal.raise_signal(signal.SIGINT)


def flaky_trial(config: dict, job: TrialJob, marker: str) -> None:
    """``run_trial`` whose first evaluation in the whole study fails (after training)."""
    import safe_bc.study.trial as mod

    original = mod.evaluate_source
    if not os.path.exists(marker):

        def fail(*args, **kwargs):
            Path(marker).touch()
            raise RuntimeError("injected failure after training")

        mod.evaluate_source = fail
    try:
        run_trial(config, job)
    finally:
        mod.evaluate_source = original


def test_interrupted_study_resumes_and_failed_trial_is_not_retrained(
    tiny_demos: Path, tmp_path: Path
) -> None:
    spec = small(
        tmp_path, tiny_demos, trials=3, max_concurrent=1, max_failures=1, screen_episodes=0
    )
    trial_fn = functools.partial(flaky_trial, marker=str(tmp_path / "failed"))
    first = run_study(
        spec,
        progress=False,
        callbacks=[InterruptOnce(str(tmp_path / "interrupted"))],
        trial_fn=trial_fn,
    )
    assert (tmp_path / "failed").exists() and (tmp_path / "interrupted").exists()
    assert not first.complete and first.winner is None and first.final is None
    done_first = set(first.trials.loc[first.trials["status"] == "done", "trial_id"])
    assert 1 <= len(done_first) < 3
    assert not (first.out / "best.json").exists()
    assert first.timing is not None  # an interrupted run writes its time table too
    first_tuning = first.timing.set_index("phase").loc["tuning", "seconds"]

    with pytest.raises(ValueError, match="other settings"):
        run_study(replace(spec, trials=2), progress=False, trial_fn=trial_fn)  # fewer

    second = run_study(spec, progress=False, trial_fn=trial_fn)
    t = second.trials
    assert second.complete and len(t) == 3 and t["trial_id"].is_unique
    assert (t["status"] == "done").all() and second.errors == 0
    assert done_first <= set(t["trial_id"])
    history, _ = read_table(second.out / "history.parquet")
    counts = history.groupby(["trial_id", "phase"]).size().unstack(fill_value=0)
    assert (counts["trained"] == 1).all(), counts  # never retrained
    assert (counts["evaluated"] == 1).all(), counts  # no trial ran twice
    # the trial whose evaluation failed was retried from its checkpoint
    assert t["resumed"].sum() == 1
    retried = t[t["resumed"]].iloc[0]
    assert retried["trial_id"] in done_first and retried["train_seconds"] > 0
    # the time table adds up every driver run: interrupted, resumed (the run with other
    # settings was refused before Ray started and timed nothing)
    timing, tmeta = read_table(second.out / "timing.parquet")
    assert len(tmeta["driver_runs"]) == 2
    assert timing.set_index("phase").loc["tuning", "seconds"] > first_tuning

    searcher = load_searcher(second.experiment_path)
    trials = searcher.study.get_trials(deepcopy=False)
    assert [x.state for x in trials] == [TrialState.COMPLETE] * 3
    held = searcher.constraints_by_trial()
    assert set(held) == set(t["trial_id"])
    for row in t.itertuples():
        assert held[row.trial_id]["safety"] == pytest.approx(row.constraint_safety)
    assert (second.out / "best.json").exists() and second.final is not None
    # Optuna's own storage beside the tables holds the same trials after the resume
    import optuna

    stored = optuna.load_study(
        study_name=spec.name, storage=f"sqlite:///{second.out / 'optuna.db'}"
    ).get_trials()
    assert [x.state for x in stored] == [TrialState.COMPLETE] * 3
    by_id = {x.user_attrs["tune_trial_id"]: x for x in stored}
    assert set(by_id) == set(t["trial_id"])
    for row in t.itertuples():
        assert by_id[row.trial_id].number == row.trial_number
        assert by_id[row.trial_id].constraints["safety"] == pytest.approx(row.constraint_safety)
        assert by_id[row.trial_id].value == pytest.approx(row.reward_mean)


def test_configuration_the_data_cannot_support_is_recorded_not_retried(
    tiny_demos: Path, tmp_path: Path
) -> None:
    # every scored row is critical, so the "noncritical" rest pool of eq. 5 is empty
    space = {
        "selection.eps": Float(500.0, 600.0),
        "selection.alpha": Float(0.2, 0.8),
        "selection.rest": Choice(("noncritical",)),
    }
    spec = small(tmp_path, tiny_demos, space=space, trials=1, max_failures=2)
    outcome = run_study(spec, progress=False)
    row = outcome.trials.iloc[0]
    assert outcome.complete and outcome.errors == 0 and outcome.winner is None
    assert row["status"] == "invalid" and "rest pool" in row["error"] and not row["feasible"]
    assert row["iterations"] == 1  # reported once, never retried
    assert (outcome.out / "trials.parquet").exists() and not (outcome.out / "best.json").exists()
    states = [t.state for t in load_searcher(outcome.experiment_path).study.get_trials()]
    assert states == [TrialState.FAIL]


def test_a_study_with_a_handover_delivers_a_certified_recommender(
    tiny_demos: Path, tmp_path: Path
) -> None:
    from safe_bc.data.store import data_digest
    from safe_bc.handover import HandoverConfig
    from safe_bc.study.certify import summarize_certification
    from safe_bc.study.recommender import RecommenderError, load_recommender

    handover = HandoverConfig(2.0, lookahead=6, hold=6, hold_on=("front",))
    spec = small(
        tmp_path, tiny_demos, trials=2, final_episodes=2, handover=handover,
        deferred_share_limit=0.5, certify_episodes=4, certify_seed=30,
    )  # fmt: skip
    outcome = run_study(spec, progress=False)
    out = tmp_path / "results" / "smoke"
    trials, meta = read_table(out / "trials.parquet")
    assert meta["inputs"]["demos"]["digest"] == data_digest(tiny_demos)
    assert meta["handover"] == handover.to_dict()
    assert trials["deferred_share"].notna().all() and (trials["deferred_share"] > 0).any()
    np.testing.assert_allclose(trials["constraint_deferral"], trials["deferred_share"] - 0.5)
    final, _ = read_table(out / "final.parquet")
    cands = final[final["role"] == "candidate"]
    assert (cands["deferred_share"] > 0).all() and final.set_index("method").loc[
        "plain_bc", "deferred_share"
    ] != final.set_index("method").loc["plain_bc", "deferred_share"]  # NaN: plain BC alone
    episodes, cmeta = read_table(out / "certify_episodes.parquet")
    assert set(episodes["method"]) == {"recommender", "agent_alone", "expert"}
    assert set(episodes["env_seed"]).isdisjoint(
        read_table(out / "final_episodes.parquet")[0]["env_seed"]
    )
    _, _, again = summarize_certification(episodes, spec)
    assert again == cmeta["certificate"] == outcome.certificate  # re-derived from its episodes
    with contextlib.ExitStack() as stack:  # the tiny study's closest candidate is uncertified
        if not outcome.final.feasible:
            stack.enter_context(pytest.raises(RecommenderError, match="uncertified"))
        load_recommender(out / "recommender", task="carracing", demos=tiny_demos)
    rec = load_recommender(
        out / "recommender", task="carracing", demos=tiny_demos, allow_uncertified=True
    )
    assert rec.card.source["feasible"] == outcome.final.feasible
    assert rec.card.source["winner"] == outcome.final.winner
    assert rec.card.seeds == [0, 1] and rec.card.handover == handover.to_dict()
    assert rec.card.certificate == outcome.certificate
    assert list(rec.card.limits.values()) == pytest.approx(meta["cost_limits"])
    # a finished study reprints its certificate from the recommender
    assert run_study(spec, progress=False).certificate == outcome.certificate
