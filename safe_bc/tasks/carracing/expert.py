"""Privileged scripted expert for CarRacing-v3: pure pursuit with a curvature speed profile.

The expert reads ``env.unwrapped.track`` (``(N, 4)`` rows ``(alpha, beta, x, y)``) and
``env.unwrapped.car`` (hull position, angle, linear and angular velocity); it never
looks at the pixels. It is meant to be *safe but not optimal*: it keeps all four
wheels on the road and brakes early for corners, so it scores below the best
achievable reward.

Control law, per step:

* **Steering.** Pure pursuit towards the centre-line point ``lookahead + lookahead_time
  * speed`` units of arc ahead of the car (shifted sideways by ``lateral_bias``), plus
  a yaw-rate damping term that pushes the measured yaw rate towards the one pure
  pursuit asks for (without it the car oscillates at speed).
  Beyond ``edge_offset`` from the centre line an extra (linear + quadratic) term
  steers back towards the centre, so pushes towards the grass are resisted harder
  the closer the car gets to it.
* **Speed.** A target speed from the upcoming track curvature: each centre-line point
  within ``preview`` units ahead allows ``sqrt(lateral_accel / (caution * |kappa|))``
  plus what the car can shed by braking over the distance to it; the target drops to
  ``edge_speed`` while the car is beyond ``edge_offset``. Gas and brake are
  P-controllers on the speed error; gas is cut while the car slides (``slip_cut``),
  because the rear-wheel-drive car spins under throttle when it has lost grip.

The default style plans with ~65% of the lateral grip (the car holds ~215 units/s^2)
and caps the speed at 65 units/s: it finishes most laps in 800-1000 steps (reward
~900) without touching the grass, below what an aggressive driver scores.

Angles and signs: hull forward is ``(-sin a, cos a)``, the car's right is
``(cos a, sin a)``; positive ``angularVelocity`` turns left; action ``steer > 0``
turns right. The front wheels' joint is limited to +-0.4 rad and the steer action is
the joint's target angle, so ``steer`` is (up to saturation) the wheel angle in rad.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import gymnasium as gym
import numpy as np

from safe_bc.tasks.carracing.geometry import ROAD_HALF_WIDTH

WHEELBASE: float = (80 + 82) * 0.02
"""Distance between front and rear axles of the CarRacing car, world units."""

MAX_WHEEL_ANGLE: float = 0.4
"""Joint limit of the front wheels, rad."""


@dataclass(frozen=True)
class ExpertConfig:
    """Driving style of :class:`CarRacingExpert`; the defaults are the cautious style.

    Distances are CarRacing world units (road half-width ~6.67, tiles ~3.5 apart),
    speeds units/s (the car tops out near 100), times seconds (50 steps per second).
    """

    max_speed: float = 65.0
    """Speed cap on straights, units/s."""

    caution: float = 1.0
    """Scales the curvature braking: corner speed is ``sqrt(lateral_accel / (caution *
    |kappa|))``. Larger is slower in corners, smaller faster (~0.65 plans with the full
    grip of the car, which is no longer safe)."""

    lateral_accel: float = 140.0
    """Lateral acceleration the speed profile plans with, units/s^2."""

    brake_decel: float = 40.0
    """Deceleration the speed profile assumes when braking for a corner ahead, units/s^2."""

    preview: float = 80.0
    """How far ahead (arc length, units) the speed profile looks for corners."""

    curvature_window: int = 3
    """Moving-average window (track points) smoothing the centre-line curvature."""

    lookahead: float = 6.0
    """Constant part of the pure-pursuit lookahead distance, units."""

    lookahead_time: float = 0.16
    """Speed-proportional part of the lookahead, seconds (lookahead += time * speed)."""

    steer_gain: float = 1.0
    """Multiplies the pure-pursuit wheel angle (rad) to give the steer action."""

    yaw_damping: float = 0.2
    """Steer per rad/s of yaw-rate error: measured minus the pure-pursuit yaw rate
    (speed x pursuit curvature). Damps oscillations and, at speed, stiffens the
    lateral correction."""

    edge_offset: float = 4.0
    """Lateral offset from the centre line (units) beyond which the edge term acts."""

    edge_gain: float = 0.1
    """Extra steer back towards the centre per unit of offset beyond ``edge_offset``;
    it makes the expert resist pushes towards the grass (e.g. drift perturbations)."""

    edge_quad: float = 0.1
    """Quadratic part of the edge term: extra steer per squared unit beyond
    ``edge_offset``, so the resistance stiffens close to the grass."""

    edge_speed: float = 45.0
    """Speed target (units/s) while the car is beyond ``edge_offset``: near the grass
    the expert slows down, which also damps the lateral swing after a push."""

    speed_gain: float = 0.1
    """Gas per unit/s the car is below the target speed."""

    brake_gain: float = 0.04
    """Brake per unit/s the car is above the target speed (plus ``brake_margin``)."""

    brake_margin: float = 2.0
    """Speed excess (units/s) tolerated before braking; below it the car only coasts."""

    slip_cut: float = 0.1
    """Traction control: gas is scaled by ``1 - |sideslip| / slip_cut`` (sideslip = angle
    between hull heading and velocity, rad), so a sliding rear-wheel-drive car does not
    spin. 0 disables it."""

    max_gas: float = 1.0
    """Upper bound of the gas action."""

    max_brake: float = 0.8
    """Upper bound of the brake action (>= 0.9 locks the wheels in CarRacing)."""

    lateral_bias: float = 0.0
    """Sideways shift of the pursued line, units; positive is right of the centre line.
    Clipped to ``+-(ROAD_HALF_WIDTH - 2)``; beyond ``edge_offset`` the edge term pulls
    back towards the centre."""

    def __post_init__(self) -> None:
        positive = (
            "max_speed",
            "caution",
            "lateral_accel",
            "brake_decel",
            "lookahead",
            "steer_gain",
            "edge_speed",
            "speed_gain",
        )
        for name in positive:
            value = getattr(self, name)
            if not value > 0:
                raise ValueError(f"ExpertConfig.{name} must be > 0, got {value!r}")
        non_negative = (
            "preview",
            "lookahead_time",
            "yaw_damping",
            "edge_offset",
            "edge_gain",
            "edge_quad",
            "slip_cut",
            "brake_gain",
            "brake_margin",
        )
        for name in non_negative:
            value = getattr(self, name)
            if not value >= 0:
                raise ValueError(f"ExpertConfig.{name} must be >= 0, got {value!r}")
        for name in ("max_gas", "max_brake"):
            value = getattr(self, name)
            if not 0 <= value <= 1:
                raise ValueError(f"ExpertConfig.{name} must be in [0, 1], got {value!r}")
        if self.curvature_window < 1:
            raise ValueError(
                f"ExpertConfig.curvature_window must be >= 1, got {self.curvature_window!r}"
            )
        if not math.isfinite(self.lateral_bias):
            raise ValueError(f"ExpertConfig.lateral_bias must be finite, got {self.lateral_bias}")

    def as_dict(self) -> dict[str, float | int]:
        """The fields as a plain dict (for logs and metadata)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


def _wrap(angle: np.ndarray) -> np.ndarray:
    """Wrap angles to ``[-pi, pi)``."""
    return (angle + np.pi) % (2 * np.pi) - np.pi


class CarRacingExpert:
    """Privileged CarRacing expert implementing the :class:`~safe_bc.policy.Policy` protocol.

    Deterministic: ``rng`` is accepted for the protocol but unused.
    """

    def __init__(self, config: ExpertConfig | None = None) -> None:
        self.config = config if config is not None else ExpertConfig()
        self._xy = np.zeros((0, 2))
        self._s = np.zeros(0)
        self._v_corner = np.zeros(0)
        self._length = 0.0
        self._idx = 0
        self._track_ref: object | None = None

    # ------------------------------------------------------------------ setup
    def reset(self, env: gym.Env, rng: np.random.Generator | None = None) -> None:
        """Read the new track; call after ``env.reset``."""
        track = np.asarray(env.unwrapped.track, dtype=np.float64)  # (N, 4)
        self._prepare(track)
        pos = np.asarray(env.unwrapped.car.hull.position, dtype=np.float64)
        d = self._xy - pos
        self._idx = int(np.argmin(np.einsum("ij,ij->i", d, d)))
        self._track_ref = env.unwrapped.track

    def _prepare(self, track: np.ndarray) -> None:
        cfg = self.config
        n = len(track)
        self._xy = track[:, 2:4].copy()  # (N, 2)
        self._beta = track[:, 1].copy()  # (N,)
        seg = np.linalg.norm(np.roll(self._xy, -1, axis=0) - self._xy, axis=1)  # (N,) i -> i+1
        self._s = np.concatenate([[0.0], np.cumsum(seg)])  # (N+1,) arc length at point i
        self._length = float(self._s[-1])
        # Signed curvature (positive = left turn) between i and i+1, smoothed.
        kappa = _wrap(np.roll(self._beta, -1) - self._beta) / np.maximum(seg, 1e-6)
        w = cfg.curvature_window
        if w > 1:
            kernel = np.ones(w) / w
            padded = np.concatenate([kappa[-w:], kappa, kappa[:w]])
            kappa = np.convolve(padded, kernel, mode="same")[w : w + n]
        self._kappa = kappa  # (N,)
        self._v_corner = np.sqrt(cfg.lateral_accel / (cfg.caution * np.abs(kappa) + 1e-9))

    # ---------------------------------------------------------------- helpers
    def _progress_index(self, pos: np.ndarray) -> int:
        """Nearest track index, searched in a window around the previous one."""
        n = len(self._xy)
        window = (self._idx + np.arange(-10, 40)) % n
        d = self._xy[window] - pos
        j = int(window[int(np.argmin(np.einsum("ij,ij->i", d, d)))])
        if np.sum((self._xy[j] - pos) ** 2) > (3 * ROAD_HALF_WIDTH) ** 2:
            d = self._xy - pos  # lost (e.g. after a spin): global search
            j = int(np.argmin(np.einsum("ij,ij->i", d, d)))
        self._idx = j
        return j

    def _point_at(self, s: float) -> tuple[np.ndarray, float]:
        """Centre-line point ``(2,)`` and heading at arc length ``s`` (wrapped)."""
        s = s % self._length
        i = int(np.searchsorted(self._s, s, side="right") - 1)
        i = min(i, len(self._xy) - 1)
        j = (i + 1) % len(self._xy)
        seg = self._s[i + 1] - self._s[i]
        frac = 0.0 if seg <= 0 else (s - self._s[i]) / seg
        p = self._xy[i] + frac * (self._xy[j] - self._xy[i])
        beta = self._beta[i] + frac * float(_wrap(self._beta[j] - self._beta[i]))
        return p, beta

    def target_speed(self, i: int, s_car: float) -> float:
        """Speed target (units/s) from the corners within ``preview`` of arc length ``s_car``."""
        cfg = self.config
        n = len(self._xy)
        ahead = int(cfg.preview / 3.0) + 2
        idx = (i + np.arange(ahead)) % n
        dist = (self._s[idx] - s_car) % self._length
        dist[dist > self._length / 2] = 0.0  # points just behind the car
        keep = dist <= cfg.preview
        allowed = np.sqrt(self._v_corner[idx][keep] ** 2 + 2 * cfg.brake_decel * dist[keep])
        return float(min(cfg.max_speed, allowed.min() if allowed.size else cfg.max_speed))

    # ------------------------------------------------------------------- act
    def act(self, obs: np.ndarray | None, env: gym.Env) -> np.ndarray:
        """Action ``(3,) float32`` = ``(steer, gas, brake)`` for the current car state."""
        cfg = self.config
        if self._track_ref is not env.unwrapped.track:  # reset() was not called
            self.reset(env)
        car = env.unwrapped.car
        pos = np.asarray(car.hull.position, dtype=np.float64)
        a = float(car.hull.angle)
        fwd = np.array([-math.sin(a), math.cos(a)])
        right = np.array([math.cos(a), math.sin(a)])
        vel = np.asarray(car.hull.linearVelocity, dtype=np.float64)
        speed = float(np.hypot(*vel))
        yaw_rate = float(car.hull.angularVelocity)  # rad/s, positive = left

        i = self._progress_index(pos)
        # Arc position of the car: nearest point plus the along-track projection.
        tangent = np.array([-math.sin(self._beta[i]), math.cos(self._beta[i])])
        s_car = float(self._s[i] + np.dot(pos - self._xy[i], tangent))

        # Steering: pure pursuit on the (biased) centre line + yaw-rate damping.
        look = cfg.lookahead + cfg.lookahead_time * speed
        target, beta_t = self._point_at(s_car + look)
        bias = float(np.clip(cfg.lateral_bias, -(ROAD_HALF_WIDTH - 2), ROAD_HALF_WIDTH - 2))
        target = target + bias * np.array([math.cos(beta_t), math.sin(beta_t)])
        d = target - pos
        x_f, x_r = float(d @ fwd), float(d @ right)
        kappa_pp = 2.0 * x_r / max(x_f * x_f + x_r * x_r, 1e-6)  # positive = turn right
        wheel = math.atan(WHEELBASE * kappa_pp)
        yaw_err = (-yaw_rate) - speed * kappa_pp  # measured minus wanted right-turn rate
        lat = float(np.dot(pos - self._xy[i], [math.cos(self._beta[i]), math.sin(self._beta[i])]))
        excess = lat - float(np.clip(lat, -cfg.edge_offset, cfg.edge_offset))
        edge = cfg.edge_gain * excess + cfg.edge_quad * excess * abs(excess)
        steer = cfg.steer_gain * wheel - cfg.yaw_damping * yaw_err - edge

        # Speed: P-control on the curvature-limited target.
        v_target = self.target_speed(i, s_car)
        if abs(lat) > cfg.edge_offset:
            v_target = min(v_target, cfg.edge_speed)
        err = v_target - speed
        gas = float(np.clip(cfg.speed_gain * err, 0.0, cfg.max_gas))
        brake = float(np.clip(cfg.brake_gain * (-err - cfg.brake_margin), 0.0, cfg.max_brake))
        if cfg.slip_cut > 0 and speed > 1.0:
            slip = math.atan2(float(vel @ right), max(float(vel @ fwd), 1e-3))
            gas *= max(0.0, 1.0 - abs(slip) / cfg.slip_cut)
        if brake > 0:
            gas = 0.0
        return np.array([np.clip(steer, -1.0, 1.0), gas, brake], dtype=np.float32)
