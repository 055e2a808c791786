"""Gymnasium conventions: ``import safe_bc`` registers every id; ``"safe_bc:<id>"`` needs
no import at all."""

from __future__ import annotations

import json
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest

import safe_bc
from safe_bc.tasks import ENV_IDS
from safe_bc.tasks.carracing import FAST_CARRACING_ID, RASTER_CARRACING_ID
from safe_bc.tasks.rehab import REHAB_ID


def test_import_registers_every_id() -> None:
    assert set(ENV_IDS) == {FAST_CARRACING_ID, RASTER_CARRACING_ID, REHAB_ID}
    for env_id in safe_bc.ENV_IDS:
        assert env_id in gym.registry


def test_make_after_import() -> None:
    env = gym.make(REHAB_ID)
    try:
        obs, info = env.reset(seed=0)
        assert obs.shape == env.observation_space.shape
        assert "safety" in info
        obs, *_ = env.step(np.zeros(2, np.float32))
        assert env.observation_space.contains(obs)
    finally:
        env.close()
    env = gym.make(FAST_CARRACING_ID, max_episode_steps=5)
    try:
        obs, _ = env.reset(seed=1)
        assert obs.shape == (96, 96, 3)
    finally:
        env.close()


_NO_IMPORT = """
import json, sys
import gymnasium as gym
assert "safe_bc" not in sys.modules
out = {}
for env_id in ("safe_bc/RehabPathway-v0", "safe_bc/CarRacingFast-v3"):
    env = gym.make("safe_bc:" + env_id, max_episode_steps=5)
    obs, info = env.reset(seed=2)
    out[env_id] = [list(obs.shape), env.spec.id]
    env.close()
out["heavy"] = sorted(m for m in ("torch", "ray") if m in sys.modules)
print(json.dumps(out))
"""


@pytest.mark.timeout(120)
def test_make_with_module_prefix_needs_no_import() -> None:
    proc = subprocess.run(
        [sys.executable, "-c", _NO_IMPORT], capture_output=True, text=True, timeout=110
    )
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["safe_bc/RehabPathway-v0"] == [[12], "safe_bc/RehabPathway-v0"]
    assert out["safe_bc/CarRacingFast-v3"] == [[96, 96, 3], "safe_bc/CarRacingFast-v3"]
    assert out["heavy"] == []  # registration pulls in neither torch nor Ray
