"""The rehab task's safer direction (``TaskSpec.safer_actions``): a lower intensity or a shorter
session never raises a safety cost of the next state, patient and day-to-day noise the same."""

from __future__ import annotations

import numpy as np

from safe_bc.tasks import make_env, task_defaults


def _next_cost(seed: int, history: list[np.ndarray], action: np.ndarray) -> np.ndarray:
    env = make_env(task_defaults("rehab").env)
    env.reset(seed=seed)
    for a in history:
        env.step(a)
    _, _, _, _, info = env.step(action)
    env.close()
    return np.asarray(info["cost"], np.float64)


def test_lower_intensity_or_duration_never_raises_a_cost() -> None:
    rehab = task_defaults("rehab")
    assert rehab.safer_actions == (-1, -1)
    rng = np.random.default_rng(0)
    checked = 0
    for seed in range(12):
        history = [rng.uniform(-1, 1, 2).astype(np.float32) for _ in range(int(rng.integers(0, 8)))]
        action = rng.uniform(-0.5, 1, 2).astype(np.float32)
        base = _next_cost(seed, history, action)
        for component in (0, 1):
            safer = action.copy()
            safer[component] -= float(rng.uniform(0.05, 0.5))
            assert (_next_cost(seed, history, safer) <= base + 1e-9).all(), (seed, component)
            checked += 1
    assert checked == 24


def test_carracing_has_no_safer_direction() -> None:
    assert task_defaults("carracing").safer_actions is None
