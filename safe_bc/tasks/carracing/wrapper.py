"""Gymnasium wrapper that adds frame-based safety costs to CarRacing's ``info``."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from safe_bc.tasks.carracing.costs import SAFETY_DIMS, costs_from_distances, pixel_distances

ZOOM_END_T = 1.0
"""CarRacing's zoom-in animation ends when the env clock ``t`` reaches 1 s (50 steps)."""


class DomainRandomizationError(ValueError):
    """Raised when colour-based safety costs are asked of a colour-randomised env."""


class CarRacingSafety(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Put the car's distance to the grass (left, front, right) and its costs in ``info``.

    Keys added to the ``info`` of ``reset`` and ``step`` (they describe the returned
    observation):

    * ``"safety"``: ``(3,) float32`` pixel distances, higher is safer;
    * ``"cost"``: ``(3,) float32`` costs, ``max_range - distance``, higher is less safe;
    * ``"warmup"``: ``True`` while the zoom-in animation runs (first ~50 steps): those
      frames are not to be scored;
    * ``"offroad"``: ``True`` when all four wheels are on grass (ground truth from the
      simulator, for evaluation only; the costs come from the frame alone);
    * ``"wheels_on_road"``: how many of the four wheels touch a road tile (simulator
      ground truth; 4 means the car is entirely on the road).

    >>> env = CarRacingSafety(gym.make("CarRacing-v3"))
    >>> obs, info = env.reset(seed=0)
    >>> info["safety"].shape, info["warmup"]
    ((3,), True)
    >>> env.close()
    """

    def __init__(self, env: gym.Env) -> None:
        gym.utils.RecordConstructorArgs.__init__(self)
        gym.Wrapper.__init__(self, env)
        if getattr(env.unwrapped, "domain_randomize", False):
            raise DomainRandomizationError(
                "CarRacingSafety reads grass by its fixed green colour; "
                "domain_randomize=True changes the colours. Create the env with "
                "domain_randomize=False."
            )
        self.safety_dims = SAFETY_DIMS

    def _augment(self, obs: np.ndarray, info: dict[str, Any]) -> dict[str, Any]:
        inner = self.env.unwrapped
        distances = pixel_distances(obs)
        info = dict(info)
        info["safety"] = distances
        info["cost"] = costs_from_distances(distances)
        info["warmup"] = bool(inner.t < ZOOM_END_T - 1e-6)
        on_road = sum(1 for w in inner.car.wheels if len(w.tiles) > 0)
        info["offroad"] = on_road == 0
        info["wheels_on_road"] = on_road
        return info

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)
        return obs, self._augment(obs, info)

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward, terminated, truncated, self._augment(obs, info)
