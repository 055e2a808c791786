"""Action perturbations: schedule, determinism, validation, and their effect on real CarRacing."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from safe_bc.tasks.carracing.expert import CarRacingExpert
from safe_bc.tasks.carracing.geometry import CAR_HALF_WIDTH, ROAD_HALF_WIDTH
from safe_bc.tasks.carracing.perturb import Perturbation, PerturbationConfig

from .conftest import STEPS, TRACK_SEEDS, RolloutStats, rollout


def _actions(n: int = 400) -> np.ndarray:
    """A fixed ``(n, 3)`` action sequence in the action space."""
    t = np.arange(n)
    return np.stack([0.5 * np.sin(t / 20), 0.5 + 0.5 * np.cos(t / 15), np.zeros(n)], 1).astype(
        np.float32
    )


def _run(config: PerturbationConfig, seed: int, actions: np.ndarray) -> np.ndarray:
    pert = Perturbation(config)
    rng = np.random.default_rng(seed)
    pert.reset(rng)
    return np.stack([pert.apply(a, t, rng) for t, a in enumerate(actions)])


@pytest.mark.parametrize("mode", ["none", "dart", "drift"])
def test_same_seed_same_actions(mode: str) -> None:
    cfg = PerturbationConfig(mode=mode)
    a = _actions()
    out1, out2 = _run(cfg, 7, a), _run(cfg, 7, a)
    np.testing.assert_array_equal(out1, out2)
    assert out1.shape == a.shape and out1.dtype == np.float32
    assert np.all(out1 >= [-1, 0, 0]) and np.all(out1 <= [1, 1, 1])
    if mode == "none":
        np.testing.assert_array_equal(out1, a)
    else:
        assert not np.array_equal(out1, _run(cfg, 8, a))


def test_dart_noise_statistics() -> None:
    cfg = PerturbationConfig(mode="dart", steer_std=0.2, gas_std=0.0, brake_std=0.0, start_step=0)
    a = np.tile(np.array([0.0, 0.5, 0.0], np.float32), (4000, 1))
    out = _run(cfg, 0, a)
    assert np.std(out[:, 0]) == pytest.approx(0.2, rel=0.1)
    np.testing.assert_array_equal(out[:, 1:], a[:, 1:])


def test_drift_schedule() -> None:
    cfg = PerturbationConfig(
        mode="drift",
        start_step=10,
        drift_prob=1.0,
        min_gap=5,
        min_duration=3,
        max_duration=3,
        min_bias=0.3,
        max_bias=0.3,
    )
    a = np.zeros((40, 3), np.float32)
    bias = _run(cfg, 0, a)[:, 0]
    # Off before start_step, then 3 steps on, 5 steps off (gap), 3 on, ...
    assert np.all(bias[:10] == 0)
    on = np.abs(bias) > 0
    np.testing.assert_array_equal(on[10:29], [1, 1, 1, 0, 0, 0, 0, 0] * 2 + [1, 1, 1])
    np.testing.assert_allclose(np.abs(bias[on]), 0.3, atol=1e-6)
    signs = [np.sign(bias[i]) for i in (10, 18, 26)]
    assert all(s in (-1, 1) for s in signs)


def test_drift_signs_are_random() -> None:
    cfg = PerturbationConfig(mode="drift", start_step=0, drift_prob=1.0, min_gap=0)
    bias = _run(cfg, 3, np.zeros((3000, 3), np.float32))[:, 0]
    assert (bias > 0).any() and (bias < 0).any()


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"mode": "gaussian"}, "mode"),
        ({"steer_std": -0.1}, "steer_std"),
        ({"gas_std": float("inf")}, "gas_std"),
        ({"brake_std": -1.0}, "brake_std"),
        ({"drift_prob": 1.5}, "drift_prob"),
        ({"min_duration": 0}, "min_duration"),
        ({"min_duration": 10, "max_duration": 5}, "max_duration"),
        ({"min_bias": 0.5, "max_bias": 0.2}, "max_bias"),
        ({"min_bias": -0.1}, "min_bias"),
        ({"max_bias": 3.0}, "max_bias"),
        ({"start_step": -1}, "start_step"),
        ({"min_gap": -5}, "min_gap"),
    ],
)
def test_config_validation(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        PerturbationConfig(**kwargs)


def test_default_is_drift() -> None:
    assert PerturbationConfig().mode == "drift"


# ----------------------------------------------------------------- real CarRacing


def test_drift_keeps_car_safe(drift_rollouts: list[RolloutStats]) -> None:
    for stats in drift_rollouts:
        assert stats.length == STEPS
        assert stats.offroad_steps == 0, stats.seed
        assert stats.reward > 150.0, stats.seed


def test_drift_moves_car_towards_edge(
    drift_rollouts: list[RolloutStats], unperturbed_rollouts: list[RolloutStats]
) -> None:
    for pert, plain in zip(drift_rollouts, unperturbed_rollouts, strict=True):
        assert pert.seed == plain.seed
        # The perturbation really acted, and the recorded label is the expert's action.
        assert np.any(pert.executed_actions[:, 0] != pert.actions[:, 0])
        # ... but stops short of the grass: every wheel stays on the road
        assert pert.min_wheels_on_road == 4, pert.seed
        assert pert.max_abs_lateral < ROAD_HALF_WIDTH - CAR_HALF_WIDTH, pert.seed
    # drifts take the car further out than the unperturbed expert goes
    gains = [p.max_abs_lateral - q.max_abs_lateral for p, q in zip(drift_rollouts,
             unperturbed_rollouts, strict=True)]  # fmt: skip
    assert max(gains) > 1.0 and max(s.max_abs_lateral for s in drift_rollouts) > 3.5


def test_drift_is_released_when_the_drift_side_gets_close() -> None:
    cfg = PerturbationConfig(drift_prob=1.0, min_duration=50, max_duration=50, start_step=0)
    pert = Perturbation(cfg)
    pert.reset()
    rng = np.random.default_rng(0)
    far = np.array([7.5, 60.0, 7.5], np.float32)
    pert.apply(np.zeros(3), 0, rng, far)
    assert pert.drifting
    side = 2 if pert.bias > 0 else 0
    close = far.copy()
    close[side] = cfg.release_distance - 0.1
    out = pert.apply(np.zeros(3), 1, rng, close)
    assert not pert.drifting and pert.bias == 0.0 and out[0] == 0.0
    # the other side being close does not release a drift
    pert = Perturbation(cfg)
    pert.reset()
    pert.apply(np.zeros(3), 0, np.random.default_rng(0), far)
    other = far.copy()
    other[2 - side] = 0.0
    pert.apply(np.zeros(3), 1, rng, other)
    assert pert.drifting


def test_same_rng_seed_same_executed_actions(carracing_env: gym.Env) -> None:
    runs = [
        rollout(
            carracing_env,
            TRACK_SEEDS[0],
            CarRacingExpert(),
            Perturbation(PerturbationConfig()),
            rng_seed=11,
            max_steps=150,
        )
        for _ in range(2)
    ]
    np.testing.assert_array_equal(runs[0].executed_actions, runs[1].executed_actions)
    np.testing.assert_array_equal(runs[0].actions, runs[1].actions)
