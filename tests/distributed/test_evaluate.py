"""Held-out evaluation with persistent actors: same numbers as in-process, disjoint seeds."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from safe_bc.bc import BCConfig, NetworkConfig, TrainConfig
from safe_bc.data.store import load_demonstrations
from safe_bc.distributed.evaluate import evaluate_policies
from safe_bc.methods.experiment import RunConfig, train_run
from safe_bc.rollout.evaluate import EvalConfig, ExpertSource, NetSource
from safe_bc.selection import SelectionConfig
from safe_bc.tasks.carracing.expert import ExpertConfig


@pytest.fixture(scope="module")
def bc_and_expert(tiny_demos):
    """``(sources, thresholds, demos)``: a BC net trained for 10 batches and the expert."""
    demos = load_demonstrations(tiny_demos)
    run = RunConfig(
        SelectionConfig(eps=3.0, alpha=0.5),
        BCConfig(network=NetworkConfig(hidden=16), train=TrainConfig(batches=10, batch_size=8)),
    )
    result, selection = train_run(demos, run)
    sources = {
        "bc": NetSource.from_model(result.model, result.config),
        "expert": ExpertSource(ExpertConfig()),
    }
    return sources, selection.thresholds, demos


def test_actors_match_in_process_and_seeds_are_held_out(bc_and_expert) -> None:
    sources, thresholds, demos = bc_and_expert
    cfg = EvalConfig(episodes=2, workers=2, max_steps=70)
    remote, steps = evaluate_policies(sources, cfg, thresholds=thresholds, progress=False)
    local, _ = evaluate_policies(
        sources,
        EvalConfig(episodes=2, workers=0, max_steps=70),
        thresholds=thresholds,
        progress=False,
    )
    pd.testing.assert_frame_equal(remote, local)
    assert list(remote["policy"]) == ["bc", "bc", "expert", "expert"]
    assert set(remote["env_seed"]).isdisjoint(set(demos.seeds.tolist()))
    for col in (
        "reward",
        "steps",
        "tiles_visited",
        "safety_mean",
        "safety_std",
        "safety_min",
        "safety_left_mean",
        "critical_share",
        "offroad_steps",
    ):
        assert col in remote, col
    assert (remote["steps"] == 70).all()
    # the per-step trace covers every step of every episode
    assert len(steps) == 4 * 70
    assert np.isclose(
        steps.groupby(["policy", "env_seed"])["reward"].sum().to_numpy(),
        remote["reward"].to_numpy(),
        atol=1e-3,
    ).all()
    # the expert out-drives an agent trained for 10 batches
    assert (
        remote[remote.policy == "expert"].reward.mean()
        > remote[remote.policy == "bc"].reward.mean()
    )


def test_train_then_evaluate_commands(tiny_demos, tmp_path, capsys) -> None:
    from safe_bc.cli.commands import main

    ckpt = tmp_path / "agent"
    args = ["train", "--demos", str(tiny_demos), "--out", str(ckpt), "--selection.eps", "3"]
    args += ["--selection.alpha", "0.5", "--bc.train.batches", "5", "--bc.train.batch-size", "8",
             "--bc.network.hidden", "16", "--quiet"]  # fmt: skip
    assert main(args) == 0
    assert (ckpt / "weights.pt").exists() and (ckpt / "selection.parquet").exists()
    out = tmp_path / "eval"
    args = ["evaluate", "--checkpoint", str(ckpt), "--episodes", "2", "--workers", "2"]
    args += ["--max-steps", "60", "--out", str(out), "--quiet"]
    assert main(args) == 0
    episodes = pd.read_parquet(out / "episodes.parquet")
    assert len(episodes) == 2 and (episodes["steps"] == 60).all()
    assert "safety_mean" in capsys.readouterr().out


def test_bad_alpha_and_missing_dataset_are_one_line_errors(tmp_path, capsys) -> None:
    from safe_bc.cli.commands import main

    assert main(["train", "--selection.alpha", "1.5", "--out", str(tmp_path / "x")]) == 2
    assert "--selection.alpha: alpha must be in [0, 1], got alpha=1.5" in capsys.readouterr().err
    assert main(["train", "--demos", str(tmp_path / "none"), "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no dataset here" in err


def test_lockstep_envs_give_the_one_env_rows(bc_and_expert) -> None:
    """envs_per_worker > 1 with ``lockstep_forward="rows"`` (one-row forward passes for the BC
    net, the expert one by one) gives exactly the rows and traces of one env at a time,
    in-process and on actors."""
    sources, thresholds, _ = bc_and_expert
    kw = {"thresholds": thresholds, "progress": False}
    one = evaluate_policies(sources, EvalConfig(episodes=3, workers=0, max_steps=60), **kw)
    for workers in (0, 2):
        cfg = EvalConfig(episodes=3, workers=workers, max_steps=60, lockstep_forward="rows")
        many = evaluate_policies(sources, cfg, envs_per_worker=2, **kw)
        pd.testing.assert_frame_equal(many[0], one[0])
        pd.testing.assert_frame_equal(
            many[1].sort_values(["policy", "env_seed", "step"]).reset_index(drop=True),
            one[1].sort_values(["policy", "env_seed", "step"]).reset_index(drop=True),
        )


def test_batched_lockstep_rows_do_not_depend_on_the_number_of_workers(bc_and_expert) -> None:
    """The default ``lockstep_forward="batched"`` deals episodes to fixed groups of
    ``envs_per_worker`` by seed order: one actor or two (each one torch thread) give the same
    rows, so a result does not depend on the cluster's size."""
    sources, thresholds, _ = bc_and_expert
    kw = {"thresholds": thresholds, "progress": False, "envs_per_worker": 2}
    runs = [
        evaluate_policies(sources, EvalConfig(episodes=3, workers=w, max_steps=60), **kw)[0]
        for w in (1, 2)
    ]
    assert EvalConfig().lockstep_forward == "batched"
    pd.testing.assert_frame_equal(runs[0], runs[1])


def test_a_trial_evaluates_its_tracks_in_lockstep_groups_of_trial_envs(
    bc_and_expert, monkeypatch
) -> None:
    """``StudySpec.trial_envs``: a trial's round is ``evaluate_policies`` over its tracks with
    ``envs_per_worker = trial_envs`` (batched forward), in-process or on its rollout workers;
    1 gives the one-env rows. Checked against the call itself, on the trial's own tracks."""
    from dataclasses import replace

    import safe_bc.study.trial as trial_mod
    from safe_bc.methods.experiment import RunConfig
    from safe_bc.study.spec import ConstraintBars, StudySpec
    from safe_bc.study.trial import TrialJob, evaluate_source

    sources, thresholds, _ = bc_and_expert
    limits = ConstraintBars(7.0, (7.0, 7.0, 7.0), 0.0)
    spec = StudySpec("s", {}, max_steps=60, eval_seed=3, final_seed=4)
    with pytest.raises(ValueError, match="trial_envs must be an integer >= 1"):
        replace(spec, trial_envs=0)
    asked: list[int] = []

    def spy(*args, **kw):
        asked.append(kw["envs_per_worker"])
        return evaluate_policies(*args, **kw)

    monkeypatch.setattr(trial_mod, "evaluate_policies", spy)
    for envs, workers in ((1, 0), (2, 0), (2, 2)):
        job = TrialJob(replace(spec, trial_envs=envs, rollout_workers=workers), "unused", limits,
                       tuple(float(x) for x in thresholds))  # fmt: skip
        got = evaluate_source(sources["bc"], RunConfig(), job, 1, 3)
        cfg = EvalConfig(episodes=3, first_episode=1, workers=0, seed=3, max_steps=60)
        want, _ = evaluate_policies({"trial": sources["bc"]}, cfg, thresholds=thresholds,
                                    progress=False, envs_per_worker=envs)  # fmt: skip
        pd.testing.assert_frame_equal(got, want)
    assert asked == [1, 2, 2]
