"""The scripted CarRacing expert on real (short) CarRacing-v3 episodes, and the geometry helper."""

from __future__ import annotations

import dataclasses

import gymnasium as gym
import numpy as np
import pytest

from safe_bc.policy import Policy
from safe_bc.tasks.carracing.expert import CarRacingExpert, ExpertConfig
from safe_bc.tasks.carracing.geometry import ROAD_HALF_WIDTH, lateral_offset, lateral_offsets

from .conftest import STEPS, RolloutStats


def test_expert_is_a_policy() -> None:
    assert isinstance(CarRacingExpert(), Policy)


def test_expert_makes_progress(unperturbed_rollouts: list[RolloutStats]) -> None:
    for stats in unperturbed_rollouts:
        assert stats.length == STEPS
        # ~1/3 lap in 350 steps is ~+300 reward; the bound is conservative.
        assert stats.reward > 150.0, stats.seed


def test_expert_never_goes_offroad(unperturbed_rollouts: list[RolloutStats]) -> None:
    for stats in unperturbed_rollouts:
        assert stats.offroad_steps == 0, stats.seed
        assert stats.min_wheels_on_road == 4, stats.seed
        assert stats.max_abs_lateral < ROAD_HALF_WIDTH - 2.0, stats.seed


def test_expert_actions_are_valid(unperturbed_rollouts: list[RolloutStats]) -> None:
    for stats in unperturbed_rollouts:
        a = stats.actions
        assert a.shape == (STEPS, 3) and a.dtype == np.float32
        assert np.all(a[:, 0] >= -1) and np.all(a[:, 0] <= 1)
        assert np.all(a[:, 1:] >= 0) and np.all(a[:, 1:] <= 1)
        np.testing.assert_array_equal(stats.executed_actions, a)  # no perturbation


def test_positive_steer_moves_car_right_of_centre(carracing_env: gym.Env) -> None:
    """The geometry convention: positive lateral offset is the side +steer turns to."""
    env = carracing_env
    env.reset(seed=5)
    track = np.asarray(env.unwrapped.track)
    for steer, sign in ((0.3, 1.0), (-0.3, -1.0)):
        env.reset(seed=5)
        for _ in range(40):
            env.step(np.array([steer, 0.3, 0.0], dtype=np.float32))
        lat = lateral_offset(track, np.asarray(env.unwrapped.car.hull.position))
        assert sign * lat > 0.5, (steer, lat)


def test_lateral_offset_on_synthetic_track() -> None:
    # A circle driven counter-clockwise: heading beta, travel (-sin b, cos b).
    beta = np.linspace(0, 2 * np.pi, 400, endpoint=False)
    r = 50.0
    track = np.stack([beta, beta, r * np.cos(beta), r * np.sin(beta)], axis=1)
    # Cross-track (cos b, sin b) points outwards here: outside is the right side.
    assert lateral_offset(track, np.array([53.0, 0.0])) == pytest.approx(3.0, abs=0.05)
    assert lateral_offset(track, np.array([0.0, 46.0])) == pytest.approx(-4.0, abs=0.05)
    pts = np.array([[53.0, 0.0], [0.0, 46.0], [-50.0, 0.0]])
    np.testing.assert_allclose(lateral_offsets(track, pts), [3.0, -4.0, 0.0], atol=0.05)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("max_speed", 0.0),
        ("caution", -1.0),
        ("lookahead", 0.0),
        ("yaw_damping", -0.1),
        ("edge_gain", -1.0),
        ("max_brake", 1.5),
        ("max_gas", -0.1),
        ("curvature_window", 0),
        ("lateral_bias", float("nan")),
    ],
)
def test_expert_config_validation(field: str, value: float) -> None:
    with pytest.raises(ValueError, match=field):
        ExpertConfig(**{field: value})


def test_expert_config_is_frozen() -> None:
    cfg = ExpertConfig()
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.max_speed = 100.0  # type: ignore[misc]
    assert cfg.as_dict()["max_speed"] == cfg.max_speed
