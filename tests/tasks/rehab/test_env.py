"""Tests of the cardiac rehabilitation pathway environment."""

from __future__ import annotations

import warnings
from dataclasses import replace

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from safe_bc.tasks import register_envs
from safe_bc.tasks.rehab import REHAB_ID
from safe_bc.tasks.rehab.env import (
    DEFAULT_N_SESSIONS,
    OBS_INDEX,
    OBS_NAMES,
    REHAB_SAFETY_DIMS,
    RehabConfig,
    RehabPathwayEnv,
    RehabSafetyLimits,
    action_to_prescription,
    age_predicted_hr_max,
    costs_from_safety,
    hrr_fraction,
    is_violation,
    karvonen_target_hr,
    prescription_to_action,
    rehab_costs,
    rehab_safety,
    sample_patient,
    training_load,
    training_stimulus,
)


def _actions(n: int, seed: int = 0) -> np.ndarray:
    """``(n, 2)`` fixed pseudo-random actions in the action box."""
    return np.random.default_rng(seed).uniform(-1, 1, size=(n, 2)).astype(np.float32)


def _rollout(env: gym.Env, seed: int, actions: np.ndarray) -> dict[str, np.ndarray]:
    """Observations ``(T+1, 12)``, rewards ``(T,)``, safety/costs ``(T+1, 3)`` of a rollout."""
    obs, info = env.reset(seed=seed)
    out = {"obs": [obs], "rew": [], "safety": [info["safety"]], "cost": [info["cost"]]}
    for a in actions:
        obs, r, terminated, truncated, info = env.step(a)
        out["obs"].append(obs)
        out["rew"].append(r)
        out["safety"].append(info["safety"])
        out["cost"].append(info["cost"])
        if terminated or truncated:
            break
    return {k: np.asarray(v) for k, v in out.items()}


# ------------------------------------------------------------------ gym contract
def test_check_env_passes_without_warnings() -> None:
    register_envs()
    env = gym.make(REHAB_ID)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)


def test_register_is_idempotent_and_limits_episode_to_programme() -> None:
    register_envs()
    register_envs()
    assert gym.spec(REHAB_ID).max_episode_steps == DEFAULT_N_SESSIONS
    env = gym.make(REHAB_ID)
    assert env.get_wrapper_attr("safety_dims") == REHAB_SAFETY_DIMS
    env.reset(seed=0)
    for t in range(DEFAULT_N_SESSIONS):
        _, _, terminated, truncated, _ = env.step(np.zeros(2, np.float32))
        assert terminated == (t == DEFAULT_N_SESSIONS - 1)
    assert truncated


def test_seeded_reset_is_deterministic() -> None:
    actions = _actions(DEFAULT_N_SESSIONS)
    a = _rollout(RehabPathwayEnv(), 7, actions)
    b = _rollout(RehabPathwayEnv(), 7, actions)
    for key in a:
        np.testing.assert_array_equal(a[key], b[key])
    c = _rollout(RehabPathwayEnv(), 8, actions)
    assert not np.array_equal(a["obs"], c["obs"])


def test_patients_differ_across_seeds() -> None:
    env = RehabPathwayEnv()
    patients = []
    for seed in range(20):
        env.reset(seed=seed)
        patients.append(env.patient)
    ages = {round(p.age, 6) for p in patients}
    resp = np.array([p.responsiveness for p in patients])
    assert len(ages) == 20
    assert resp.std() > 0.1
    assert all(50 <= p.age <= 80 and 3.5 <= p.capacity <= 10 for p in patients)


def test_patient_option_replays_a_patient() -> None:
    patient = sample_patient(np.random.default_rng(3))
    env = RehabPathwayEnv()
    env.reset(seed=1, options={"patient": patient})
    assert env.patient == patient
    with pytest.raises(TypeError):
        env.reset(options={"patient": {"age": 60}})


def test_observation_layout_and_bounds() -> None:
    env = RehabPathwayEnv()
    obs, info = env.reset(seed=2)
    assert obs.shape == (len(OBS_NAMES),) and obs.dtype == np.float32
    assert obs[OBS_INDEX["progress"]] == 0.0
    assert obs[OBS_INDEX["last_intensity"]] == 0.0 and obs[OBS_INDEX["last_duration"]] == 0.0
    assert obs[OBS_INDEX["hr_peak_hrr"]] == 0.0
    assert obs[OBS_INDEX["capacity_rel"]] == pytest.approx(1.0, abs=0.05)
    assert not info["offroad"] and info["warmup"] is False
    obs, *_ = env.step(prescription_to_action(0.55, 25.0))
    assert obs[OBS_INDEX["last_intensity"]] == pytest.approx(0.55, abs=1e-5)
    assert obs[OBS_INDEX["last_duration"]] * 60 == pytest.approx(25.0, abs=1e-4)
    assert obs[OBS_INDEX["progress"]] == pytest.approx(1 / DEFAULT_N_SESSIONS)
    # Extreme actions keep the observation inside its space.
    for a in (np.array([1.0, 1.0]), np.array([-1.0, -1.0]), np.array([5.0, -7.0])):
        env.reset(seed=4)
        for _ in range(DEFAULT_N_SESSIONS):
            obs, *_ = env.step(a.astype(np.float32))
            assert env.observation_space.contains(obs)


def test_step_rejects_nan_and_requires_reset() -> None:
    env = RehabPathwayEnv()
    with pytest.raises(RuntimeError):
        env.step(np.zeros(2, np.float32))
    env.reset(seed=0)
    with pytest.raises(ValueError):
        env.step(np.array([np.nan, 0.0], np.float32))


# ------------------------------------------------------------------ pure functions
def test_hr_max_and_karvonen_for_a_60_year_old() -> None:
    assert age_predicted_hr_max(60) == pytest.approx(166.0)  # Tanaka: 208 - 0.7 * 60
    assert age_predicted_hr_max(60, "fox") == pytest.approx(160.0)  # Fox: 220 - 60
    # Resting 70 bpm: HRR = 96 bpm; 80 % HRR = 70 + 76.8 = 146.8 bpm.
    assert karvonen_target_hr(70.0, 166.0, 0.8) == pytest.approx(146.8)
    assert karvonen_target_hr(70.0, 160.0, 0.4) == pytest.approx(106.0)
    assert hrr_fraction(146.8, 70.0, 166.0) == pytest.approx(0.8)
    with pytest.raises(ValueError):
        age_predicted_hr_max(60, "astrand")  # type: ignore[arg-type]


def test_costs_and_safety_on_hand_computed_cases() -> None:
    # 60-year-old, rest 70 bpm, peak 140 bpm: (140 - 70) / (166 - 70) = 0.7292 HRR.
    hr_frac = hrr_fraction(140.0, 70.0, age_predicted_hr_max(60))
    costs = rehab_costs(hr_frac, 0.4, 200.0)
    assert costs.dtype == np.float32 and costs.shape == (3,)
    np.testing.assert_allclose(costs, [70 / 96, 0.4, 2.0], atol=1e-6)
    safety = rehab_safety(costs)  # limits 0.8 HRR, 1.0, 220 mmHg
    np.testing.assert_allclose(safety, [0.8 - 70 / 96, 0.6, 0.2], atol=1e-6)
    assert not is_violation(safety)
    np.testing.assert_allclose(costs_from_safety(safety), costs, atol=1e-6)
    # Peak 150 bpm: 80/96 = 0.833 HRR is above the 80 % bound.
    over = rehab_safety(rehab_costs(hrrr := hrr_fraction(150.0, 70.0, 166.0), 0.4, 200.0))
    assert over[0] == pytest.approx(0.8 - hrrr, abs=1e-6) and over[0] < 0
    assert is_violation(over)
    # SBP 230 mmHg breaks the 220 mmHg ceiling; fatigue 1.1 breaks the 1.0 limit.
    assert rehab_safety(rehab_costs(0.5, 0.2, 230.0))[2] == pytest.approx(-0.1, abs=1e-6)
    assert rehab_safety(rehab_costs(0.5, 1.1, 150.0))[1] == pytest.approx(-0.1, abs=1e-6)
    strict = RehabSafetyLimits(hr_zone_upper=0.7, fatigue_limit=0.8, sbp_limit_mmhg=200.0)
    np.testing.assert_allclose(
        rehab_safety(rehab_costs(0.65, 0.5, 190.0), strict), [0.05, 0.3, 0.1], atol=1e-6
    )
    with pytest.raises(ValueError):
        RehabSafetyLimits(hr_zone_upper=1.5)


def test_action_mapping_round_trip_and_clipping() -> None:
    assert action_to_prescription(np.array([-1.0, -1.0])) == pytest.approx((0.3, 10.0))
    assert action_to_prescription(np.array([1.0, 1.0])) == pytest.approx((0.9, 60.0))
    assert action_to_prescription(np.array([3.0, -3.0])) == pytest.approx((0.9, 10.0))
    for i, d in ((0.4, 15.0), (0.65, 45.0), (0.8, 20.0)):
        assert action_to_prescription(prescription_to_action(i, d)) == pytest.approx(
            (i, d), abs=1e-5
        )
    assert training_load(0.5, 30.0) == pytest.approx(1.0)
    assert training_stimulus(1.0, 30.0) == pytest.approx(4.0)


# ------------------------------------------------------------------ safety in info, reward
def test_info_safety_matches_costs_and_offroad() -> None:
    env = RehabPathwayEnv()
    limits = RehabSafetyLimits()
    _, info = env.reset(seed=5)
    for a in _actions(DEFAULT_N_SESSIONS, seed=5):
        for key in ("safety", "cost"):
            assert info[key].dtype == np.float32 and info[key].shape == (3,)
        np.testing.assert_allclose(info["safety"], limits.as_array() - info["cost"], atol=1e-6)
        assert info["offroad"] == bool((info["safety"] < 0).any())
        assert info["warmup"] is False
        _, _, _, _, info = env.step(a)
    # The HR cost is the session's peak HR as a fraction of HRR.
    hr_max = age_predicted_hr_max(env.patient.age)
    assert info["cost"][0] == pytest.approx(
        hrr_fraction(info["hr_peak_bpm"], info["hr_rest_bpm"], hr_max), abs=1e-5
    )
    assert info["cost"][2] == pytest.approx(info["sbp_peak_mmhg"] / 100, abs=1e-5)
    assert info["cost"][1] == pytest.approx(info["fatigue"], abs=1e-5)


def test_reward_does_not_depend_on_cost_parameters() -> None:
    actions = _actions(DEFAULT_N_SESSIONS, seed=11)
    base = RehabConfig()
    strict = replace(
        base,
        limits=RehabSafetyLimits(hr_zone_upper=0.6, fatigue_limit=0.4, sbp_limit_mmhg=170.0),
    )
    a = _rollout(RehabPathwayEnv(base), 3, actions)
    b = _rollout(RehabPathwayEnv(strict), 3, actions)
    np.testing.assert_array_equal(a["rew"], b["rew"])
    np.testing.assert_array_equal(a["obs"], b["obs"])
    np.testing.assert_array_equal(a["cost"], b["cost"])
    assert (b["safety"] < a["safety"]).all()  # same states, tighter margins


def test_hr_zone_violation_from_aggressive_sessions() -> None:
    env = RehabPathwayEnv()
    for seed in range(5):
        env.reset(seed=seed)
        _, _, _, _, info = env.step(prescription_to_action(0.9, 60.0))
        assert info["cost"][0] > 0.8 and info["safety"][0] < 0 and info["offroad"]


def test_exhaustion_costs_reward() -> None:
    """Well-being: the discomfort penalty makes exhausting sessions pay badly."""
    moderate = np.tile(prescription_to_action(0.6, 40.0), (DEFAULT_N_SESSIONS, 1))
    exhausting = np.tile(prescription_to_action(0.9, 60.0), (DEFAULT_N_SESSIONS, 1))
    rm = np.mean([_rollout(RehabPathwayEnv(), s, moderate)["rew"].sum() for s in range(10)])
    rx = np.mean([_rollout(RehabPathwayEnv(), s, exhausting)["rew"].sum() for s in range(10)])
    assert rm > 0 > rx
