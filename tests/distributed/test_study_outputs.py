"""A study's outputs: a finished study's rerun reads every table and recommender file whole
before it says the study finished (a damaged one is refused in one line naming the file)."""

from __future__ import annotations

import json
from pathlib import Path

import optuna
import pandas as pd
import pytest

from safe_bc.bc import BCConfig, NetworkConfig
from safe_bc.bc.net import BCNet, ModelSpec
from safe_bc.data.store import write_tables_atomic
from safe_bc.study.plan import StudyPlan, plan_study
from safe_bc.study.recommender import RecommenderCard, write_recommender
from safe_bc.study.run import FINISHED, finished_outcome
from safe_bc.study.spec import Float, StudySpec, trial_table


def _optuna_copy(path: Path, name: str, trials: int) -> None:
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storage = optuna.storages.RDBStorage(f"sqlite:///{path}")
    study = optuna.create_study(study_name=name, storage=storage)
    for _ in range(trials):
        study.tell(study.ask({"x": optuna.distributions.FloatDistribution(0, 1)}), 1.0)
    storage.remove_session()
    storage.engine.dispose()


def _recommender(out: Path) -> None:
    config = BCConfig(network=NetworkConfig(hidden=8))
    net = BCNet(ModelSpec((4,), (-1.0,), (1.0,)), config.preprocess, config.network)
    card = RecommenderCard(
        task="rehab", env={"env_id": "x"}, limits={"a": 1.0}, handover=None, expert={},
        demos={"digest": "sha256:0"}, seeds=[0], run_config={}, source={"feasible": True},
        certificate={"episodes": 2},
    )  # fmt: skip
    write_recommender(out, card, {0: (net, config)})


@pytest.fixture
def finished(tmp_path: Path) -> StudyPlan:
    """A finished study's folder, every output written as the study writes it."""
    spec = StudySpec(
        "mine", {"selection.alpha": Float(0.0, 1.0)}, trials=2, results=tmp_path / "results",
        storage=str(tmp_path / "ray"),
    )  # fmt: skip
    plan = plan_study(spec, fresh=False, command="", final=True)
    out = plan.out
    out.mkdir(parents=True)
    rows = [
        {"trial_id": t, "trial_number": i, "status": "done", "reward_mean": 1.0 + i,
         "constraint": -1.0, "safety_mean": 7.0, "threshold": 6.0, "selection.alpha": 0.5}
        for i, t in enumerate(("a", "b"))
    ]  # fmt: skip
    meta = {"threshold": 6.0, "experiment_path": plan.exp_path}
    small = pd.DataFrame({"trial_id": ["a", "b"], "x": [1.0, 2.0]})
    tables = {"trials": trial_table(rows, spec.params), "history": small, "final": small,
              "final_episodes": small, "final_paired": small, "timing": small,
              "certify": small, "certify_episodes": small}  # fmt: skip
    write_tables_atomic(out, tables, meta)
    (out / "best.json").write_text(json.dumps({"trial_id": "b", "feasible": True}))
    _recommender(out / "recommender")
    _optuna_copy(out / "optuna.db", spec.name, spec.trials)
    (out / FINISHED).write_text(json.dumps(plan.finished))
    return plan


@pytest.mark.parametrize(
    "damaged",
    [
        "history.parquet",
        "timing.parquet",
        "certify.parquet",
        "certify_episodes.parquet",
        "final_paired.parquet",
        "recommender/seed_0/weights.pt",
        "recommender/seed_0/config.json",
        "recommender/recommender.json",
    ],
)
def test_a_finished_study_with_a_damaged_table_or_recommender_file_is_refused_naming_it(
    finished: StudyPlan, damaged: str
) -> None:
    outcome = finished_outcome(finished)
    assert outcome is not None and outcome.certificate == {"episodes": 2}
    file = finished.out / damaged
    file.write_bytes(b"")
    with pytest.raises(ValueError) as e:
        finished_outcome(finished)
    message = str(e.value)
    assert "\n" not in message and str(file) in message, message
    assert f"delete {finished.out / FINISHED} and rerun the same command" in message


def test_a_finished_study_without_its_history_table_is_refused(finished: StudyPlan) -> None:
    (finished.out / "history.parquet").unlink()
    with pytest.raises(ValueError, match=r"history\.parquet: no such file"):
        finished_outcome(finished)


# --- a committed study is never overwritten by another one ---------------------------------------


def _committed(tmp_path: Path) -> Path:
    """A study file and its committed study (``results/mine/`` tracked by git, no Tune
    experiment): the study file's path."""
    import subprocess

    study = tmp_path / "mine.py"
    study.write_text(
        "from pathlib import Path\n"
        "from safe_bc.study.spec import Float, StudySpec\n"
        "STUDY = StudySpec('mine', {'selection.alpha': Float(0.0, 1.0)}, trials=3,\n"
        f"    results=Path({str(tmp_path / 'results')!r}), storage={str(tmp_path / 'ray')!r},\n"
        f"    demos=Path({str(tmp_path / 'demos')!r}))\n"
    )
    from safe_bc.study.spec import load_study

    spec = load_study(study)
    out = spec.results / spec.name
    out.mkdir(parents=True)
    write_tables_atomic(
        out, {"trials": pd.DataFrame({"trial_id": ["a"]})}, {"study": spec.summary()}
    )
    (out / "study.json").write_text(json.dumps({"trials": 3}))  # an older record: no settings
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-C", str(tmp_path)]
    for args in (["init", "-q"], ["add", "results"], ["commit", "-qm", "study"]):
        subprocess.run(git + args, check=True, capture_output=True)
    return study


@pytest.mark.parametrize(
    "flags,what",
    [
        (["--trials", "2"], "trials 3 -> 2"),
        (["--more-trials", "2"], "trials 3 -> 5"),
        (["--set", "batches=500"], "batches 2000 -> 500"),
    ],
)
def test_another_study_over_a_committed_one_is_refused_in_one_line_naming_the_ways_out(
    tmp_path: Path, capsys, flags: list[str], what: str
) -> None:
    import ray

    from safe_bc.cli.commands import main

    study = _committed(tmp_path)
    out = tmp_path / "results" / "mine"
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    started = ray.is_initialized()
    assert main(["tune", str(study), *flags]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"safe-bc tune: error: {out} holds a committed")
    assert f"other settings ({what})" in err and "--results DIR" in err and "--fresh" in err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # nothing touched
    assert ray.is_initialized() == started and not (tmp_path / "ray").exists()


def test_the_committed_studys_own_settings_may_run_it_again(tmp_path: Path) -> None:
    from safe_bc.study.resume import check_published
    from safe_bc.study.spec import load_study

    spec = load_study(_committed(tmp_path))
    plan = plan_study(spec, fresh=False, command="", final=True)
    check_published(plan.out, plan.settings)  # a reproduction: git diff compares it
