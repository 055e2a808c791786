"""A tiny rehab study with the bound constraint and a two-seed objective, end to end."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from safe_bc.metrics import clopper_pearson_upper
from safe_bc.rollout.collect import CollectConfig
from safe_bc.study.spec import load_study
from safe_bc.tasks import task_defaults

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_bound_constraints_and_two_seed_objective_end_to_end(
    ray_session, rehab_demos: Path, tmp_path: Path
) -> None:
    import optuna
    import pyarrow.fs as pafs

    from safe_bc.study.run import run_study
    from safe_bc.study.trial import stored_checkpoint

    spec = replace(
        load_study(REPO / "tune_jobs" / "rehab.py"),
        demos=rehab_demos,
        collect=CollectConfig.for_task(task_defaults("rehab"), episodes=8, workers=1),
        storage=str(tmp_path / "ray"),
        results=tmp_path / "results",
        trials=2,
        batches=20,
        eval_episodes=3,
        screen_episodes=0,
        train_seeds=2,
        reward_bound=0.9,
        violation_bound=0.95,
        violation_share_limit=0.6,
        final_episodes=4,
        final_candidates=1,
        final_train_seeds=2,
        startup_trials=2,
    )
    outcome = run_study(spec, progress=False)
    t = outcome.trials
    assert outcome.complete and outcome.errors == 0, t[["status", "error"]]
    done = t[t["status"] == "done"]
    assert len(done) >= 1
    assert (done["train_seeds"] == 2).all() and (done["episodes"] == 6).all()
    assert (done["reward_lcb"] <= done["reward_mean"]).all()
    for row in done.itertuples():
        k = round(row.any_violation * 6)
        assert row.violation_share_ucb == pytest.approx(clopper_pearson_upper(k, 6, 0.95))
        assert row.constraint_violation == pytest.approx(row.violation_share_ucb - 0.6)
    stored = optuna.load_study(
        study_name=spec.name, storage=f"sqlite:///{outcome.out / 'optuna.db'}"
    ).get_trials()
    by_id = {x.user_attrs["tune_trial_id"]: x for x in stored}
    for row in done.itertuples():  # the objective Optuna saw is the lower bound
        assert by_id[row.trial_id].value == pytest.approx(row.reward_lcb)
    # every seed's net is in the trial's checkpoint (a retry or a resume reuses them)
    folder = Path(outcome.experiment_path) / f"trial_{done.iloc[0].trial_id}"
    nets, extra = stored_checkpoint(pafs.LocalFileSystem(), str(folder), all_seeds=True)
    assert extra["seeds"] == [0, 1] and len(nets) == 2
    sd0, sd1 = (n.state_dict() for n in nets)
    assert any(not torch.equal(sd0[k], sd1[k]) for k in sd0)  # two seeds, two nets
    # the final phase reports what the winner's fresh episodes certify
    best = json.loads((outcome.out / "best.json").read_text())
    assert best["certified"].startswith("at most ") and "95% one-sided" in best["certified"]
    assert "violation_share_ucb" in outcome.final.table
