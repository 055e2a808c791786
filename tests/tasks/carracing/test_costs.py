"""Frame-based safety distances agree with the simulator's geometry."""

from __future__ import annotations

import numpy as np
import pytest

from safe_bc.metrics import combined
from safe_bc.tasks import make_env
from safe_bc.tasks.carracing.costs import (
    MAX_RANGE,
    costs_from_distances,
    pixel_distances,
)
from safe_bc.tasks.carracing.expert import CarRacingExpert, ExpertConfig
from safe_bc.tasks.carracing.geometry import lateral_offset
from safe_bc.tasks.env_config import EnvConfig


def _road_frame(left_edge: int, right_edge: int) -> np.ndarray:
    frame = np.zeros((96, 96, 3), np.uint8)
    frame[..., 0] = frame[..., 2] = 100
    frame[..., 1] = 202
    frame[:, left_edge:right_edge] = 102
    return frame


def test_synthetic_road_distances() -> None:
    d = pixel_distances(_road_frame(34, 62))
    # road cols 34..61: left of col 44 lie cols 34..44 (11 px), right of col 51: 51..61 (11 px)
    np.testing.assert_allclose(d, [11, 66, 11])
    assert costs_from_distances(d).tolist() == [34, 0, 34]


def test_partial_edge_pixel_counts_as_fraction() -> None:
    frame = _road_frame(34, 62)
    frame[:, 33, 1] = 151  # half-blended edge pixel: greenness 0.51 -> stops, adds 0.49
    assert pixel_distances(frame)[0] == pytest.approx(11.49, abs=1e-4)


def test_wrong_shape_is_refused() -> None:
    with pytest.raises(ValueError, match="96, 96, 3"):
        pixel_distances(np.zeros((84, 96, 3), np.uint8))


def test_costs_are_bounded() -> None:
    c = costs_from_distances(np.array([[-3.0, 100.0, 10.0]]))
    assert c.tolist() == [[MAX_RANGE[0], 0.0, MAX_RANGE[2] - 10]]


def _drive(seed: int, steps: int, expert_cfg: ExpertConfig, steer_bias: float = 0.0):
    env = make_env(EnvConfig(max_episode_steps=steps))
    expert = CarRacingExpert(expert_cfg)
    obs, info = env.reset(seed=seed)
    expert.reset(env, np.random.default_rng(seed))
    track = np.asarray(env.unwrapped.track)
    rows = []
    for t in range(steps):
        action = expert.act(obs, env).copy()
        # swing the car across the road so the offsets cover its width
        action[0] = np.clip(action[0] + steer_bias * np.sin(t / 15.0), -1, 1)
        obs, _, term, trunc, info = env.step(action)
        pos = np.asarray(env.unwrapped.car.hull.position)
        if not info["warmup"]:
            rows.append((lateral_offset(track, pos), *info["safety"], info["offroad"]))
        if term or trunc:
            break
    env.close()
    return np.array(rows, dtype=np.float64)


def test_left_minus_right_tracks_true_lateral_offset() -> None:
    rows = np.concatenate(
        [_drive(seed, 260, ExpertConfig(max_speed=35.0), steer_bias=0.35) for seed in (1, 2)]
    )
    on_road = rows[:, 4] == 0
    lat, left, right = rows[on_road, 0], rows[on_road, 1], rows[on_road, 3]
    assert np.ptp(lat) > 4.0, "drive must sweep across the road to test anything"
    r = np.corrcoef(lat, left - right)[0, 1]
    assert r > 0.95, f"pixel left-right vs true offset correlation {r:.3f}"
    # positive offset = right of centre = more road on the left
    assert np.polyfit(lat, left - right, 1)[0] > 0


def test_offroad_frames_have_distance_near_zero() -> None:
    env = make_env(EnvConfig(max_episode_steps=400))
    _, info = env.reset(seed=5)
    seen = []
    for t in range(400):
        steer = 0.0 if t < 60 else 0.6
        _obs, _, term, trunc, info = env.step(np.array([steer, 0.5, 0.0], np.float32))
        if info["offroad"] and not info["warmup"]:
            seen.append(combined(info["safety"]))
        if term or trunc or len(seen) > 40:
            break
    env.close()
    assert len(seen) > 10, "the car never left the road"
    assert np.median(seen) < 1.0


def _reference_pixel_distances(frame: np.ndarray) -> np.ndarray:
    """The whole-frame computation ``pixel_distances`` replaced (greenness of every row above
    the car's bottom, one ``_ray_distance`` call per side): its values must not change."""
    from safe_bc.tasks.carracing.costs import (
        CAR_COLS,
        CAR_ROWS,
        FRONT_START,
        LEFT_START,
        RIGHT_START,
        _ray_distance,
        greenness,
    )

    g = greenness(frame[: CAR_ROWS.stop])
    left = _ray_distance(g[CAR_ROWS, LEFT_START::-1]).mean()
    right = _ray_distance(g[CAR_ROWS, RIGHT_START:]).mean()
    front = _ray_distance(g[FRONT_START::-1, CAR_COLS].T).mean()
    return np.array([left, front, right], np.float32)


def _assert_bits_equal(frame: np.ndarray) -> None:
    got, want = pixel_distances(frame), _reference_pixel_distances(frame)
    assert got.dtype == want.dtype == np.float32
    assert np.array_equal(got.view(np.uint32), want.view(np.uint32)), (got, want)


def test_ray_pixels_cover_each_ray_once() -> None:
    from safe_bc.tasks.carracing.costs import _RAY_COLS, _RAY_PAD, _RAY_ROWS

    assert _RAY_ROWS.shape == _RAY_COLS.shape == _RAY_PAD.shape == (30, 66)
    rays = zip(_RAY_ROWS, _RAY_COLS, _RAY_PAD, strict=True)
    real = [set(zip(r[~p], c[~p], strict=True)) for r, c, p in rays]
    assert [len(s) for s in real] == [45] * 24 + [66] * 6
    assert len(set().union(*real)) == 24 * 45 + 6 * 66


def test_pixel_distances_bit_identical_to_whole_frame_computation() -> None:
    """Random frames (grass and road everywhere, partial edges) and real CarRacing frames
    (road, curbs, grass, the zoom-in) give the very same float32 distances."""
    rng = np.random.default_rng(0)
    for i in range(400):
        frame = rng.integers(0, 256, (96, 96, 3), dtype=np.uint8)
        if i % 2:  # more grass-like pixels
            frame[..., 1] = np.maximum(frame[..., 1], rng.integers(100, 256, (96, 96)))
        if i % 5 == 0:  # plain road with a random edge on each side
            frame[:] = _road_frame(int(rng.integers(0, 45)), int(rng.integers(51, 97)))
        _assert_bits_equal(frame)
    env = make_env(EnvConfig(max_episode_steps=150))
    try:
        obs, _ = env.reset(seed=3)
        _assert_bits_equal(obs)
        for t in range(150):
            steer = 0.0 if t < 55 else 0.7 * np.sin(t / 9.0)
            obs, _, term, trunc, _ = env.step(np.array([steer, 0.6, 0.0], np.float32))
            _assert_bits_equal(obs)
            if term or trunc:
                break
    finally:
        env.close()
