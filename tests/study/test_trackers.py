"""``safe-bc tune --tracker``: Ray Tune's W&B and MLflow integrations on a tiny Tune run, offline
(W&B offline mode, a local MLflow SQLite store), skipped where the package is absent; the flag
reaching the study's callbacks; a missing package refused in one line."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Any

import pytest
from ray import tune

from safe_bc.study.trackers import check_tracker, tracker_callbacks


def _two_reports(config: dict[str, Any]) -> None:
    for i in range(2):
        tune.report({"reward_mean": 10.0 * (i + 1) + config["alpha"], "phase": "evaluated"})


def _tiny_run(tmp_path: Path, callbacks: list[Any]) -> None:
    tuner = tune.Tuner(
        _two_reports,
        param_space={"alpha": tune.grid_search([0.5])},
        run_config=tune.RunConfig(
            name="tiny", storage_path=str(tmp_path / "ray"), callbacks=callbacks, verbose=0
        ),
    )
    grid = tuner.fit()
    assert not grid.errors


def test_mlflow_tracker_records_every_report(ray_session, tmp_path, monkeypatch) -> None:
    pytest.importorskip("mlflow")
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    out = tmp_path / "results" / "tiny"
    (callback,) = tracker_callbacks("mlflow", "tiny", out)
    _tiny_run(tmp_path, [callback])
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=f"sqlite:///{out / 'mlflow.db'}")
    experiment = client.get_experiment_by_name("tiny")
    (run,) = client.search_runs([experiment.experiment_id])
    history = client.get_metric_history(run.info.run_id, "reward_mean")
    assert [m.value for m in history] == [10.5, 20.5]


def test_wandb_tracker_offline(ray_session, tmp_path, monkeypatch) -> None:
    pytest.importorskip("wandb")
    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_SILENT", "true")
    monkeypatch.delenv("WANDB_DIR", raising=False)
    out = tmp_path / "results" / "tiny"
    (callback,) = tracker_callbacks("wandb", "tiny", out)
    _tiny_run(tmp_path, [callback])
    runs = list((out / "wandb").glob("offline-run-*"))
    assert len(runs) == 1 and list(runs[0].glob("*.wandb"))  # the run's records, to sync


def test_missing_tracker_package_is_one_line(monkeypatch) -> None:
    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "wandb" else real(name, *a)
    )
    with pytest.raises(ValueError, match=r"pip install 'safe_bc\[wandb\]'"):
        check_tracker("wandb")
    assert tracker_callbacks("none", "s", Path("unused")) == []


def test_tracker_flag_reaches_the_study(tmp_path, monkeypatch) -> None:
    """``--tracker mlflow`` and ``api.tune(callbacks=...)`` reach ``run_study``'s callbacks."""
    pytest.importorskip("mlflow")
    import safe_bc.cli.api as api
    import safe_bc.study.run as study
    from safe_bc.cli.commands import parse

    seen: dict[str, Any] = {}

    class Stop(Exception):
        pass

    def fake_run_study(spec: Any, **kw: Any) -> Any:
        seen.update(kw)
        raise Stop

    monkeypatch.setattr(study, "run_study", fake_run_study)
    monkeypatch.setattr(api, "_check_study_demos", lambda spec: None)
    smoke = Path(__file__).resolve().parents[2] / "tune_jobs" / "smoke.py"
    command, job = parse(["tune", str(smoke), "--tracker", "mlflow",
                          "--results", str(tmp_path / "results")])  # fmt: skip
    assert command == "tune" and job.tracker == "mlflow"
    mine = tune.Callback()
    with pytest.raises(Stop):
        api.tune(job, callbacks=[mine])
    kinds = [type(c).__name__ for c in seen["callbacks"]]
    assert kinds == ["MLflowLoggerCallback", "Callback"] and seen["callbacks"][1] is mine
