"""Tests of the guideline (blueprint) clinician for the rehabilitation pathway."""

from __future__ import annotations

from dataclasses import dataclass, replace

import gymnasium as gym
import numpy as np
import pytest

from safe_bc.policy import Policy
from safe_bc.tasks import register_envs
from safe_bc.tasks.rehab import REHAB_ID
from safe_bc.tasks.rehab.env import (
    DEFAULT_N_SESSIONS,
    OBS_INDEX,
    OBS_NAMES,
    REHAB_SAFETY_DIMS,
    RehabPathwayEnv,
    action_to_prescription,
    sample_patient,
)
from safe_bc.tasks.rehab.expert import ConstantPrescription, GuidelineConfig, GuidelineExpert

N_PATIENTS = 50


@dataclass(frozen=True)
class Summary:
    """Per-episode results of :func:`_evaluate` (``(N,)`` arrays; ``costs`` is ``(N*T, 3)``)."""

    returns: np.ndarray
    violations: np.ndarray
    costs: np.ndarray


def _evaluate(policy: Policy, n: int = N_PATIENTS, seed0: int = 0) -> Summary:
    """Run ``policy`` on ``n`` seeded patients."""
    env = RehabPathwayEnv()
    returns, violations, costs = [], [], []
    for seed in range(seed0, seed0 + n):
        obs, info = env.reset(seed=seed)
        policy.reset(env, np.random.default_rng(1000 + seed))
        total, bad, done = 0.0, 0, False
        while not done:
            obs, reward, terminated, truncated, info = env.step(policy.act(obs, env))
            total += reward
            bad += int(info["offroad"])
            costs.append(info["cost"])
            done = terminated or truncated
        returns.append(total)
        violations.append(bad)
    return Summary(np.array(returns), np.array(violations), np.array(costs))


def _obs(**values: float) -> np.ndarray:
    """A ``(12,)`` observation with mid-programme defaults, overridden by ``values``."""
    obs = np.zeros(len(OBS_NAMES), np.float32)
    defaults = {
        "hr_rest": 0.7,
        "hr_peak": 0.6,
        "hr_peak_hrr": 0.55,
        "sbp_peak": 170 / 200,
        "sbp_rest": 130 / 200,
        "fatigue": 0.3,
        "capacity": 0.6,
        "capacity_rel": 1.05,
        "progress": 0.3,
        "age": 0.65,
        "last_intensity": 0.5,
        "last_duration": 30 / 60,
    }
    defaults.update(values)
    for name, v in defaults.items():
        obs[OBS_INDEX[name]] = v
    return obs


NO_JITTER = GuidelineConfig(clinician_jitter=0.0)


def test_implements_policy_protocol() -> None:
    assert isinstance(GuidelineExpert(), Policy)
    assert isinstance(ConstantPrescription(0.5, 30.0), Policy)


def test_starts_low_and_acts_in_the_box() -> None:
    env = RehabPathwayEnv()
    patient = replace(sample_patient(np.random.default_rng(0)), sbp_rest=130.0)
    obs, _ = env.reset(seed=0, options={"patient": patient})
    expert = GuidelineExpert(NO_JITTER)
    expert.reset(env, np.random.default_rng(0))
    action = expert.act(obs, env)
    assert action.shape == (2,) and action.dtype == np.float32
    assert np.all(np.abs(action) <= 1.0)
    assert action_to_prescription(action) == pytest.approx((0.40, 15.0), abs=1e-5)


def test_cautious_start_for_high_resting_blood_pressure() -> None:
    expert = GuidelineExpert(NO_JITTER)
    entry = _obs(last_intensity=0.0, last_duration=0.0, sbp_rest=160 / 200)
    assert expert.prescribe(entry) == pytest.approx((0.30, 15.0))
    entry = _obs(last_intensity=0.0, last_duration=0.0, sbp_rest=130 / 200)
    assert expert.prescribe(entry) == pytest.approx((0.40, 15.0))


def test_progresses_without_warning_signs() -> None:
    expert = GuidelineExpert(NO_JITTER)
    assert expert.prescribe(_obs()) == pytest.approx((0.51, 31.0))


@pytest.mark.parametrize(
    ("signs", "expected"),
    [
        ({"hr_peak_hrr": 0.75}, (0.45, 31.0)),  # HR near the 80 % HRR bound: back off
        ({"hr_peak_hrr": 0.69}, (0.50, 31.0)),  # HR in the hold band: hold intensity
        ({"sbp_peak": 212 / 200}, (0.45, 31.0)),  # high SBP: back off
        ({"fatigue": 0.85}, (0.475, 25.0)),  # high fatigue: shorter and a little easier
        ({"fatigue": 0.72}, (0.50, 30.0)),  # fatigue in the hold band: hold both
    ],
)
def test_backs_off_on_warning_signs(signs: dict[str, float], expected: tuple) -> None:
    expert = GuidelineExpert(NO_JITTER)
    assert expert.prescribe(_obs(**signs)) == pytest.approx(expected)


def test_stays_within_guideline_caps() -> None:
    expert = GuidelineExpert(NO_JITTER)
    i, d = expert.prescribe(_obs(last_intensity=0.65, last_duration=45 / 60))
    assert (i, d) == pytest.approx((0.65, 45.0))
    i, d = expert.prescribe(_obs(last_intensity=0.30, last_duration=10 / 60, hr_peak_hrr=0.9))
    assert (i, d) == pytest.approx((0.30, 11.0))  # floors of the action box


def test_clinician_jitter_varies_the_protocol_reproducibly() -> None:
    expert = GuidelineExpert()
    configs = []
    for seed in (0, 0, 1):
        expert.reset(None, np.random.default_rng(seed))
        configs.append(expert.episode_config)
    assert configs[0] == configs[1] != configs[2]
    assert configs[0].clinician_jitter == GuidelineConfig().clinician_jitter
    expert = GuidelineExpert(NO_JITTER)
    expert.reset(None, np.random.default_rng(5))
    assert expert.episode_config == NO_JITTER
    with pytest.raises(ValueError):
        GuidelineConfig(hr_hold=0.8, hr_backoff=0.7)


def test_guideline_is_safe_and_gets_near_the_limits() -> None:
    result = _evaluate(GuidelineExpert())
    assert result.violations.sum() == 0
    assert result.returns.mean() > 5.0
    # Some sessions come close to the limits (the critical subset is not empty).
    max_cost = result.costs.max(axis=0)
    assert max_cost[0] > 0.72  # HR within 8 % HRR of the 80 % HRR bound
    assert max_cost[1] > 0.6  # fatigue
    assert max_cost[2] > 2.0  # SBP above 200 mmHg (limit 220)


def test_aggressive_constant_policy_violates_safety() -> None:
    result = _evaluate(ConstantPrescription(0.9, 60.0), n=10)
    assert (result.violations > 0).all()
    assert result.violations.mean() > 0.9 * DEFAULT_N_SESSIONS


def test_guideline_is_not_optimal() -> None:
    guideline = _evaluate(GuidelineExpert())
    accelerated = _evaluate(GuidelineExpert(GuidelineConfig.accelerated()))
    assert accelerated.returns.mean() > 1.2 * guideline.returns.mean()
    # The better pathway exists within the limits: it stays (almost) as safe.
    assert (accelerated.violations > 0).mean() <= 0.04


def test_rollout_records_a_safe_episode() -> None:
    rollout = pytest.importorskip("safe_bc.rollout.episode")
    register_envs()
    env = gym.make(REHAB_ID)
    episode = rollout.run_episode(env, GuidelineExpert(), seed=3, rng=np.random.default_rng(0))
    assert len(episode) == DEFAULT_N_SESSIONS
    assert episode.safety_dims == REHAB_SAFETY_DIMS
    assert episode.observations.shape == (DEFAULT_N_SESSIONS, len(OBS_NAMES))
    assert episode.costs.shape == (DEFAULT_N_SESSIONS, 3)
    assert not episode.offroad.any() and not episode.warmup.any()
    assert episode.terminated[-1] and not episode.terminated[:-1].any()
    assert episode.total_reward > 0
