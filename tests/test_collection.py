"""The default demonstrations are safe and their limit d_s is meaningful (real CarRacing)."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from safe_bc.data.demos import Demonstrations
from safe_bc.rollout.collect import CollectConfig, EpisodeMaker
from safe_bc.tasks import task_defaults
from safe_bc.tasks.carracing.costs import MAX_RANGE


class WheelLog(gym.Wrapper):
    """Records the simulator's wheel contacts (``info["wheels_on_road"]``) of every state."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.wheels: list[int] = []

    def reset(self, **kwargs: Any):
        obs, info = self.env.reset(**kwargs)
        self.wheels = [info["wheels_on_road"]]
        return obs, info

    def step(self, action: Any):
        out = self.env.step(action)
        self.wheels.append(out[-1]["wheels_on_road"])
        return out


def default_episodes(ids: list[int]) -> tuple[Demonstrations, list[int]]:
    """Episodes ``ids`` of the default CarRacing collection, and the fewest wheels on the road
    seen in any of their states."""
    maker = EpisodeMaker(CollectConfig.for_task(task_defaults("carracing")))
    maker.env = WheelLog(maker.env)
    try:
        episodes, fewest = [], []
        for i in ids:
            episodes.append(maker.make(i))
            fewest.append(min(maker.env.wheels))
    finally:
        maker.close()
    return Demonstrations.from_episodes(episodes), fewest


def check_safe(demos: Demonstrations, fewest: list[int]) -> None:
    assert fewest == [4] * len(fewest)  # no wheel ever left the road (simulator)
    scored = demos.safety[demos.scored]
    assert (scored.min(axis=0) > 0.5).all()  # the pixels agree: never at the grass edge
    limits = demos.limits
    assert (limits < MAX_RANGE - 0.5).all() and (limits > 0).all()  # strictly inside the range


def test_default_demonstration_episode_is_safe_with_a_meaningful_limit() -> None:
    demos, fewest = default_episodes([0])
    assert len(demos) > 700  # a full lap, drifts included
    check_safe(demos, fewest)
    # drifts really took the car towards the edges: closer than the unperturbed expert's ~5.5
    assert demos.safety[demos.scored][:, [0, 2]].min() < 5.0


@pytest.mark.slow
def test_every_default_demonstration_episode_is_safe() -> None:
    demos, fewest = default_episodes(list(range(task_defaults("carracing").episodes)))
    check_safe(demos, fewest)
    assert np.isfinite(demos.limits).all()
