"""Perturbations of the executed action, so demonstrations visit states near the road edge.

The expert's own action is recorded as the label; the perturbed action is what the
environment executes. Two kinds:

* ``"dart"``: DART-style (Laskey et al. 2017) i.i.d. Gaussian noise on every
  executed action.
* ``"drift"``: scheduled drifts. Now and then (after a random idle time) a steering
  bias of random sign and magnitude is added for a random number of steps, so the car
  drifts towards the left or right edge while the expert fights it; then the bias is
  released and the expert steers back to the centre. The demonstrations thus contain
  near-edge states *and* the expert's way out of them. A drift is also released early
  once the car's measured distance to the grass on the drift side falls below
  ``release_distance`` (the ``safety`` reading of the current frame), so the car stops
  short of the grass: the demonstrations stay safe and the expert's worst cost ``d_s``
  stays strictly inside the measurable range.

All randomness comes from the ``np.random.Generator`` passed to :meth:`Perturbation.reset`
and :meth:`Perturbation.apply`: the same seed gives the same executed actions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Literal

import numpy as np

PerturbationMode = Literal["none", "dart", "drift"]

ACTION_LOW = np.array([-1.0, 0.0, 0.0], dtype=np.float32)
"""Lower bound of the CarRacing continuous action ``(steer, gas, brake)``."""

ACTION_HIGH = np.array([1.0, 1.0, 1.0], dtype=np.float32)
"""Upper bound of the CarRacing continuous action ``(steer, gas, brake)``."""


@dataclass(frozen=True)
class PerturbationConfig:
    """Which perturbation to apply and its parameters (steps are env steps, 50 per second).

    The defaults (``"drift"``) take the expert's car from the centre (~7.5 px from the
    grass on either side) towards one edge on every drift and release it ~6 px from the
    grass; momentum carries it to ~3 px before the expert has turned it round. No wheel
    leaves the road (checked against the simulator's wheel contacts by the tests).
    """

    mode: PerturbationMode = "drift"
    """``"none"`` (execute the expert's action), ``"dart"`` (Gaussian noise on every
    action) or ``"drift"`` (scheduled steering-bias drifts)."""

    start_step: int = 50
    """No perturbation before this step (the car gets going during the zoom-in)."""

    steer_std: float = 0.3
    """``"dart"``: standard deviation of the noise added to steer."""

    gas_std: float = 0.1
    """``"dart"``: standard deviation of the noise added to gas."""

    brake_std: float = 0.0
    """``"dart"``: standard deviation of the noise added to brake."""

    drift_prob: float = 0.02
    """``"drift"``: probability per idle step (after ``min_gap`` steps) that a drift
    starts; the mean idle time is ``min_gap + 1 / drift_prob`` steps."""

    min_gap: int = 60
    """``"drift"``: steps after a drift ends before the next one may start (recovery)."""

    min_duration: int = 25
    """``"drift"``: shortest drift, steps."""

    max_duration: int = 80
    """``"drift"``: longest drift, steps (inclusive)."""

    min_bias: float = 0.4
    """``"drift"``: smallest steering bias magnitude added during a drift."""

    max_bias: float = 0.65
    """``"drift"``: largest steering bias magnitude; the sign (left/right) is random."""

    release_distance: float = 6.0
    """``"drift"``: release a drift as soon as the distance to the grass on the drift side
    (pixels, the ``safety`` reading of the frame) is below this; ``0`` never releases early
    (the car may then reach the grass edge: distance 0, so ``d_s`` is the full range)."""

    def __post_init__(self) -> None:
        if self.mode not in ("none", "dart", "drift"):
            raise ValueError(
                f"PerturbationConfig.mode must be 'none', 'dart' or 'drift', got {self.mode!r}"
            )
        for name in ("steer_std", "gas_std", "brake_std", "min_bias", "max_bias",
                     "release_distance"):  # fmt: skip
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(
                    f"PerturbationConfig.{name} must be finite and >= 0, got {value!r}"
                )
        for name in ("start_step", "min_gap"):
            value = getattr(self, name)
            if value < 0:
                raise ValueError(f"PerturbationConfig.{name} must be >= 0, got {value!r}")
        if not 0 <= self.drift_prob <= 1:
            raise ValueError(
                f"PerturbationConfig.drift_prob must be in [0, 1], got {self.drift_prob!r}"
            )
        if self.min_duration < 1:
            raise ValueError(
                f"PerturbationConfig.min_duration must be >= 1, got {self.min_duration!r}"
            )
        if self.max_duration < self.min_duration:
            raise ValueError(
                f"PerturbationConfig.max_duration ({self.max_duration}) must be >= "
                f"min_duration ({self.min_duration})"
            )
        if self.max_bias < self.min_bias:
            raise ValueError(
                f"PerturbationConfig.max_bias ({self.max_bias}) must be >= "
                f"min_bias ({self.min_bias})"
            )
        if self.max_bias > 2:
            raise ValueError(
                f"PerturbationConfig.max_bias must be <= 2 (steer range is [-1, 1]), "
                f"got {self.max_bias!r}"
            )

    def as_dict(self) -> dict[str, str | int | float]:
        """The fields as a plain dict (for logs and metadata)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


class Perturbation:
    """Stateful perturbation of one episode; call :meth:`reset` at the start of each."""

    def __init__(self, config: PerturbationConfig | None = None) -> None:
        self.config = config if config is not None else PerturbationConfig()
        self._active = False
        self._bias = 0.0
        self._drift_end = -1
        self._next_allowed = 0

    @property
    def bias(self) -> float:
        """Steering bias being added now (0.0 when no drift is active)."""
        return self._bias

    @property
    def drifting(self) -> bool:
        """Whether a drift is active (as of the last :meth:`apply`)."""
        return self._active

    def reset(self, rng: np.random.Generator | None = None) -> None:
        """Start a new episode: no drift active. ``rng`` is accepted for symmetry, unused."""
        self._active = False
        self._bias = 0.0
        self._drift_end = -1
        self._next_allowed = self.config.start_step

    def apply(
        self,
        action: np.ndarray,
        t: int,
        rng: np.random.Generator,
        safety: np.ndarray | None = None,
    ) -> np.ndarray:
        """Executed action ``(3,) float32`` for the expert's ``action`` ``(3,)`` at step ``t``.

        Call once per step with increasing ``t``; the result is clipped to the action
        space ``[-1, 1] x [0, 1] x [0, 1]``. ``safety`` is the current frame's ``(3,)``
        distances to the grass ``(left, front, right)``; with it, a drift is released
        once the drift side's distance is below ``release_distance``.
        """
        cfg = self.config
        out = np.asarray(action, dtype=np.float64).reshape(3).copy()
        if cfg.mode == "dart":
            if t >= cfg.start_step:
                out += rng.normal(size=3) * np.array([cfg.steer_std, cfg.gas_std, cfg.brake_std])
        elif cfg.mode == "drift":
            self._update_drift(t, rng)
            if self._active and safety is not None and self._too_close(safety):
                self._release(t)
            out[0] += self._bias
        return np.clip(out, ACTION_LOW, ACTION_HIGH).astype(np.float32)

    def _too_close(self, safety: np.ndarray) -> bool:
        """Whether the drift side's distance ``(left, front, right)[side]`` is below the limit."""
        side = 2 if self._bias > 0 else 0  # +steer drifts right
        return float(np.asarray(safety).reshape(-1)[side]) < self.config.release_distance

    def _release(self, t: int) -> None:
        self._active = False
        self._bias = 0.0
        self._next_allowed = t + self.config.min_gap

    def _update_drift(self, t: int, rng: np.random.Generator) -> None:
        cfg = self.config
        if self._active and t >= self._drift_end:
            self._release(t)
        idle = not self._active and t >= max(self._next_allowed, cfg.start_step)
        if idle and rng.random() < cfg.drift_prob:
            duration = int(rng.integers(cfg.min_duration, cfg.max_duration + 1))
            magnitude = float(rng.uniform(cfg.min_bias, cfg.max_bias))
            sign = 1.0 if rng.random() < 0.5 else -1.0
            self._active = True
            self._bias = sign * magnitude
            self._drift_end = t + duration
