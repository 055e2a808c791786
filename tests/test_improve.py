"""Constrained improvement (safe_bc.methods.improve): shield, multiplier, determinism, resume."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from safe_bc.data.curves import read_events
from safe_bc.methods.improve import (
    ImproveConfig,
    ImprovedSource,
    Improver,
    Shield,
    _load_start,
    improve,
    multiplier_update,
    observed_costs,
)
from safe_bc.selection import CriticalZone

REHAB = "safe_bc/RehabPathway-v0"
TINY = ImproveConfig(
    iterations=4,
    episodes_per_iter=4,
    n_envs=4,
    update_epochs=2,
    minibatch_size=32,
    anchor_batch=16,
    critic_hidden=16,
    critic_warmup=1,
    eval_every=2,
    eval_episodes=3,
    checkpoint_every=2,
)


@pytest.fixture(scope="module")
def start(rehab_start: Path) -> Path:
    return rehab_start


def _weights(out: Path) -> dict[str, torch.Tensor]:
    return torch.load(out / "policy" / "weights.pt", weights_only=True)


def _same(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


# ------------------------------------------------------------------ the multiplier
def test_multiplier_rises_above_budget_falls_below_and_clips_at_zero():
    assert multiplier_update(1.0, episode_cost=0.5, budget=0.1, lr=0.5) == pytest.approx(1.2)
    assert multiplier_update(1.0, episode_cost=0.0, budget=0.1, lr=0.5) == pytest.approx(0.95)
    assert multiplier_update(0.02, episode_cost=0.0, budget=0.1, lr=0.5) == 0.0  # clipped
    assert multiplier_update(0.0, episode_cost=0.0, budget=0.0, lr=0.5) == 0.0  # stays
    assert multiplier_update(9.9, episode_cost=5.0, budget=0.0, lr=1.0, lam_max=10.0) == 10.0


def test_multiplier_in_training_follows_the_cost(start):
    """Budget 0: lambda never falls, and rises exactly when an iteration's rollouts cost."""
    s, demos = _load_start(start, None)
    with torch.random.fork_rng(devices=[]):
        agent = Improver(s, demos, replace(TINY, cost_margin=0.5, cost_budget=0.0, lambda_lr=0.5))
        for _ in range(3):
            before = agent.lam
            row = agent.iterate()
            assert row["train_episode_cost"] > 0  # margin 0.5: every session costs
            assert agent.lam == pytest.approx(before + 0.5 * row["train_episode_cost"])
        off = Improver(s, demos, replace(TINY, lagrangian=False, cost_margin=0.5))
        off.iterate()
        assert off.lam == 0.0
    agent.envs.close()
    off.envs.close()


# ------------------------------------------------------------------ the shield
def test_observed_costs_match_the_env_without_noise():
    from safe_bc.tasks.rehab.env import RehabConfig, RehabPathwayEnv, prescription_to_action

    env = RehabPathwayEnv(RehabConfig(obs_noise=0.0))
    obs, info = env.reset(seed=3)
    for _ in range(5):
        obs, _, _, _, info = env.step(prescription_to_action(0.7, 40.0))
        measured = observed_costs(obs[None], REHAB)[0]
        assert measured[1:] == pytest.approx(info["cost"][1:], abs=1e-5)  # fatigue, SBP
        assert measured[0] == pytest.approx(info["cost"][0], abs=0.05)  # HRR vs rest HR now


def test_shield_gives_critical_states_the_imitation_action(start):
    """Evaluation policy and training rollouts: every critical state gets the start's action."""
    from safe_bc.bc import BCPolicy
    from safe_bc.rollout.evaluate import NetSource

    s, demos = _load_start(start, None)
    shield = Shield(CriticalZone(tuple(s.limits), eps=0.15, combine="any"), env_id=REHAB)
    moved = NetSource.from_model(s.model, s.config)
    last_bias = [k for k in moved.state if k.startswith("head.") and k.endswith(".bias")][-1]
    moved.state[last_bias] += 0.7  # a different policy everywhere
    policy = ImprovedSource(moved, NetSource.from_model(s.model, s.config), shield).build()
    start_policy, own = BCPolicy(s.model), moved.build()
    rng = np.random.default_rng(0)
    obs = demos.observations[rng.permutation(len(demos))[:300]]
    critical = shield.critical(obs)
    assert 0 < critical.sum() < len(obs)
    for o, c in zip(obs, critical, strict=True):
        expect = start_policy.act(o) if c else own.act(o)
        np.testing.assert_array_equal(policy.act(o), expect)

    with torch.random.fork_rng(devices=[]):
        agent = Improver(s, demos, replace(TINY, eps=0.15))
        agent.actor.mean_net.head[-1].bias.data += 0.7
        ro = agent.rollout([11, 12, 13, 14])
    agent.envs.close()
    crit = agent.shield.critical(ro.obs)
    assert crit.any() and (crit == ro.shielded).all()
    np.testing.assert_allclose(ro.actions[crit], start_policy.act_batch(ro.obs[crit]), atol=1e-6)
    assert not np.allclose(ro.actions[~crit], start_policy.act_batch(ro.obs[~crit]))


# ------------------------------------------------------------------ determinism and resume
def test_fixed_seed_gives_bit_identical_weights(start, tmp_path):
    a = improve(start, tmp_path / "a", TINY)
    improve(start, tmp_path / "b", TINY)
    improve(start, tmp_path / "c", replace(TINY, seed=1))
    assert _same(_weights(tmp_path / "a"), _weights(tmp_path / "b"))
    assert not _same(_weights(tmp_path / "a"), _weights(tmp_path / "c"))
    assert len(a.history) == TINY.iterations and a.history["val_reward"].notna().sum() == 2
    start_w = torch.load(start / "weights.pt", weights_only=True)
    assert not _same(_weights(tmp_path / "a"), start_w)  # it did move


def test_interrupted_run_resumes_to_the_same_weights(start, tmp_path):
    cfg = replace(TINY, iterations=5)
    whole = improve(start, tmp_path / "whole", cfg)

    def crash(row: dict[str, float]) -> None:
        if row["iteration"] == 3:  # the last checkpoint holds iteration 2
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        improve(start, tmp_path / "cut", cfg, on_iteration=crash)
    assert not (tmp_path / "cut" / "policy").exists()
    resumed = improve(start, tmp_path / "cut", cfg)
    assert resumed.resumed_at == 2 and resumed.iterations == 5
    assert _same(_weights(tmp_path / "whole"), _weights(tmp_path / "cut"))
    cols = [c for c in whole.history.columns if c != "seconds"]
    assert whole.history[cols].equals(resumed.history[cols])
    # the curve in TensorBoard: rewritten from the history, no iteration twice after the resume
    events = read_events(tmp_path / "cut")
    assert events[events["tag"] == "improve/train_reward"]["step"].tolist() == [1, 2, 3, 4, 5]
    with pytest.raises(ValueError, match="another run"):
        improve(start, tmp_path / "cut", replace(cfg, anchor_coef=2.0))


def test_cli_and_evaluation_of_a_run(start, tmp_path, capsys):
    from safe_bc.cli.commands import main
    from safe_bc.distributed.evaluate import evaluate
    from safe_bc.rollout.evaluate import EvalConfig
    from safe_bc.tasks.env_config import EnvConfig

    out = tmp_path / "run"
    argv = ["improve", "--start", str(start), "--out", str(out), "--iterations", "2",
            "--episodes-per-iter", "4", "--no-lagrangian", "--quiet"]  # fmt: skip
    assert main(argv) == 0
    assert "shield, 2 iterations (fresh)" in capsys.readouterr().out
    source = ImprovedSource.from_run(out)
    assert source.shield is not None and source.imitation is not None
    cfg = EvalConfig(episodes=2, workers=0, env=EnvConfig(REHAB), eps=0.05)
    result = evaluate(
        {"improved": source}, cfg, np.asarray(source.shield.zone.limits), progress=False
    )
    assert len(result.episodes) == 2 and result.episodes["steps"].eq(30).all()
    assert main([*argv[:-1], "--iterations", "0"]) == 2
    assert "--iterations: iterations must be >= 1" in capsys.readouterr().err


def test_a_finished_run_is_returned_untouched_without_its_state(start, tmp_path):
    """Rerunning a finished run (its state.pt gone, as in a git checkout) rewrites nothing."""
    done = improve(start, tmp_path / "run", TINY)
    (tmp_path / "run" / "state.pt").unlink()
    files = sorted(p for p in (tmp_path / "run").rglob("*") if p.is_file())
    stamps = [p.stat().st_mtime_ns for p in files]
    again = improve(start, tmp_path / "run", TINY)
    assert [p.stat().st_mtime_ns for p in files] == stamps
    assert again.resumed_at == again.iterations == TINY.iterations
    assert again.kept_iteration == done.kept_iteration
    pd.testing.assert_frame_equal(again.history, done.history)
    longer = improve(start, tmp_path / "run", replace(TINY, iterations=TINY.iterations + 1))
    assert longer.resumed_at == 0  # another config: no finished run of it, a fresh one


def test_carracing_zoom_in_frames_carry_no_cost() -> None:
    """The improvement engine must not charge the zoom-in (the evaluation path does not score
    it): a LocalEnvs step reports zero costs while ``info["warmup"]``, the env's costs after."""
    import numpy as np

    from safe_bc.methods.improve import LocalEnvs
    from safe_bc.tasks import make_env
    from safe_bc.tasks.carracing import CARRACING_ID
    from safe_bc.tasks.env_config import EnvConfig

    group, plain = LocalEnvs(CARRACING_ID, 1), make_env(EnvConfig(CARRACING_ID))
    try:
        group.reset([3])
        plain.reset(seed=3)
        action = np.zeros((1, 3), np.float32)
        for _ in range(60):
            cost = group.step([0], action)[0][4]
            info = plain.step(action[0])[4]
            expected = np.zeros(3) if info["warmup"] else np.asarray(info["cost"], np.float64)
            np.testing.assert_array_equal(cost, expected)
        assert not info["warmup"] and np.asarray(info["cost"]).any()
    finally:
        group.close()
        plain.close()


def test_the_lagrangian_margin_is_the_tasks_unless_set() -> None:
    from safe_bc.methods import METHODS
    from safe_bc.methods.improve.config import ImproveConfig
    from safe_bc.tasks import task_defaults

    assert ImproveConfig().cost_margin is None
    spec = METHODS["improve"]
    assert spec.identify(ImproveConfig(), "rehab")["cost_margin"] == 0.05
    assert spec.identify(ImproveConfig(), "carracing")["cost_margin"] == 1.0  # px, not 0.05
    assert spec.identify(ImproveConfig(cost_margin=0.2), "carracing")["cost_margin"] == 0.2
    assert task_defaults("rehab").cost_margin == 0.05
    with pytest.raises(ValueError, match="cost_margin"):
        ImproveConfig(cost_margin=-1.0)
