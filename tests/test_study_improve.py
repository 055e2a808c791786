"""The optional improvement stage of a study: spec keys, the trained-net entry point and (slow)
a tiny rehab study with improvement end to end on the local Ray."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from safe_bc.methods.improve import ImproveConfig, ImprovedSource, improve_from_net
from safe_bc.rollout.collect import CollectConfig
from safe_bc.run_config import RunConfig
from safe_bc.study.spec import Choice, Float, StudySpec, load_study, split_params
from safe_bc.tasks import task_defaults

REPO = Path(__file__).resolve().parents[1]
TINY = ImproveConfig(
    shield=False,
    iterations=2,
    episodes_per_iter=4,
    n_envs=4,
    update_epochs=1,
    minibatch_size=32,
    anchor_batch=16,
    critic_hidden=16,
    critic_warmup=1,
    eval_every=1,
    eval_episodes=2,
    checkpoint_every=1,
)


def test_improve_keys_set_the_improvement_config_and_leave_the_run_config_alone():
    spec = StudySpec(
        "s",
        {"selection.alpha": Float(0.0, 1.0), "improve.cost_margin": Float(0.02, 0.2),
         "improve.shield": Choice((False, True))},
        improve=ImproveConfig(iterations=7),
    )  # fmt: skip
    params = {"selection.alpha": 0.3, "improve.cost_margin": 0.1, "improve.shield": True}
    assert split_params(params) == ({"selection.alpha": 0.3},
                                    {"improve": {"cost_margin": 0.1, "shield": True}})  # fmt: skip
    assert spec.run_config(params).selection.alpha == 0.3
    assert [stage.name for stage in spec.stages()] == ["improve"]
    icfg = spec.stage_config("improve", params, seed=4)
    assert (icfg.cost_margin, icfg.shield, icfg.iterations, icfg.seed) == (0.1, True, 7, 4)
    assert spec.summary()["improve"]["iterations"] == 7
    plain = StudySpec("p", {"selection.alpha": Float(0.0, 1.0)})
    assert plain.stage_config("improve", {}, seed=0) is None and plain.summary()["improve"] is None
    assert plain.stages() == []


def test_improve_keys_without_a_stage_or_with_a_bad_value_are_rejected():
    with pytest.raises(ValueError, match="has none"):
        StudySpec("s", {"improve.cost_margin": Float(0.0, 0.1)})
    with pytest.raises(ValueError, match="no field 'margin'"):
        StudySpec("s", {"improve.margin": Float(0.0, 0.1)}, improve=ImproveConfig())
    with pytest.raises(ValueError, match="cost_margin must be >= 0"):
        StudySpec("s", {"improve.cost_margin": Float(-0.1, 0.1)}, improve=ImproveConfig())


def test_rehab_improve_study_file_loads_with_its_stage():
    spec = load_study(REPO / "tune_jobs" / "rehab_improve.py")
    assert spec.improve is not None and spec.trials == 8
    assert all(k.startswith("improve.") for k in spec.params)
    assert spec.run_config({}).selection.eps == 0.05


def test_improve_from_net_writes_a_start_improves_and_resumes(rehab_demos: Path, tmp_path: Path):
    from safe_bc.data.store import load_demonstrations
    from safe_bc.methods.experiment import train_run
    from safe_bc.tasks import action_bounds, task_defaults

    env = task_defaults("rehab").env
    run = RunConfig()
    run = replace(run, selection=replace(run.selection, eps=0.05))
    run = replace(run, bc=replace(run.bc, train=replace(run.bc.train, batches=20)))
    result, _ = train_run(load_demonstrations(rehab_demos), run, action_bounds=action_bounds(env))
    args = (result.model, run.bc, run.selection, str(rehab_demos), env.env_id, tmp_path / "imp")
    source, done = improve_from_net(*args, TINY)
    assert isinstance(source, ImprovedSource) and source.imitation is None  # no shield
    assert done.iterations == 2 and done.resumed_at == 0
    assert (tmp_path / "imp" / "start" / "selection.parquet").exists()
    again = improve_from_net(*args, TINY)[1]
    assert again.resumed_at == 2  # the same weights and settings: resumed, nothing redone
    shielded, other = improve_from_net(*args, replace(TINY, shield=True))
    assert shielded.imitation is not None and other.resumed_at == 0  # other settings: new run


def tiny_study(file: str, demos: Path, tmp_path: Path, **kw) -> StudySpec:
    """The study file ``file`` of tune_jobs/ shrunk to the 8 programmes of ``demos`` and
    :data:`TINY`'s improvement, writing under ``tmp_path``; ``kw`` overrides."""
    return replace(
        load_study(REPO / "tune_jobs" / file),
        demos=demos,
        collect=CollectConfig.for_task(task_defaults("rehab"), episodes=8, workers=1),
        storage=str(tmp_path / "ray"),
        results=tmp_path / "results",
        improve=TINY,
        batches=20,
        eval_episodes=2,
        final_episodes=2,
        **kw,
    )


@pytest.mark.slow
def test_tiny_study_with_improvement_end_to_end(ray_session, rehab_demos: Path, tmp_path: Path):
    from safe_bc.study.run import run_study

    spec = tiny_study(
        "rehab_improve.py", rehab_demos, tmp_path, trials=2, screen_episodes=0,
        final_candidates=1, final_train_seeds=2, startup_trials=2,
    )  # fmt: skip
    outcome = run_study(spec, progress=False)
    t = outcome.trials
    assert outcome.complete and outcome.errors == 0, t[["status", "error"]]
    assert (t["status"] == "done").all() and (t["improve_kept_iteration"] >= 1).all()
    assert outcome.final is not None and outcome.final.winner is not None
    roots = list((outcome.out / "final_improve").glob("*/seed*/run/policy"))
    assert len(roots) == 2  # the candidate improved for both seeds; plain BC is not


def test_a_studys_recommender_is_the_improved_agent_it_certified(
    ray_session, rehab_demos: Path, tmp_path: Path
):
    """The recommender ships the agent the certification evaluated (the stage's output, not
    the net the stage started from): loaded and evaluated on the certificate's patients, it
    gives the certificate's episodes."""
    import pandas as pd

    from safe_bc.cli.commands import main
    from safe_bc.data.store import read_table
    from safe_bc.methods.rounds import weights_digest
    from safe_bc.study.run import run_study

    spec = tiny_study(
        "beyond_rehab.py", rehab_demos, tmp_path, final_train_seeds=1, certify_episodes=3,
        final_workers=0,
        threshold=-1e9,  # constraints every agent meets: the recommender is certified
        violation_bound=None, violation_tolerance=1.0, deferred_share_limit=1.0,
    )  # fmt: skip
    outcome = run_study(spec, progress=False)
    assert outcome.certificate is not None
    rec = outcome.out / "recommender"
    winner = outcome.final.winner
    improved = ImprovedSource.from_run(outcome.out / "final_improve" / winner / "seed0" / "run")
    start, _ = load_checkpoint_of(outcome.out / "final_improve" / winner / "seed0" / "start")
    shipped, _ = load_checkpoint_of(rec / "seed_0")
    assert weights_digest(shipped.state_dict()) == weights_digest(improved.improved.state)
    assert weights_digest(shipped.state_dict()) != weights_digest(start.state_dict())
    argv = ["evaluate", "--recommender", str(rec), "--recommender-seed", "0", "--eval-seed",
            str(spec.certify_seed), "--episodes", "3", "--workers", "0", "--out",
            str(tmp_path / "again"), "--quiet"]  # fmt: skip
    assert main(argv) == 0
    again = pd.read_parquet(tmp_path / "again" / "episodes.parquet")
    cert, _ = read_table(outcome.out / "certify_episodes.parquet")
    cert = cert[(cert["method"] == "recommender") & (cert["train_seed"] == 0)]
    assert list(again["env_seed"]) == list(cert["env_seed"])
    # the certification ran the patients in lockstep (one batched forward pass), this run one
    # at a time: the same decisions, float32 rounding apart
    assert list(again["deferred_steps"]) == list(cert["deferred_steps"])
    assert list(again["violation_steps"]) == list(cert["violation_steps"])
    assert list(again["reward"]) == pytest.approx(list(cert["reward"]), rel=1e-6)


def load_checkpoint_of(path: Path):
    from safe_bc.bc import load_checkpoint

    return load_checkpoint(path)
