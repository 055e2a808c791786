"""The optimised raster env draws exactly the frames, and computes exactly the costs, of the
implementation that ``results/ablation/renderer/`` measured (``raster_reference.py``): frames,
rewards, terminations and every ``info`` value equal step by step over real episodes (zoom-in,
visited tiles, grass, hard turns), and ``pixel_distances`` bit for bit on random frames.

Both sides run in the same process, so the comparison holds on whatever CPU runs it; it was
shown on the AMD EPYC CI machine (AVX-512) only. On another machine type the compiled kernels
check themselves against the numpy code once per process and fall back to it if they ever
disagree (``safe_bc.tasks.carracing.compiled``)."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

from safe_bc.tasks import make_env
from safe_bc.tasks.carracing import RASTER_CARRACING_ID, costs
from safe_bc.tasks.carracing.costs import pixel_distances
from safe_bc.tasks.carracing.raster_render import RasterCarRacing
from safe_bc.tasks.env_config import EnvConfig
from tests.tasks.carracing.raster_reference import (
    REFERENCE_RASTER_ID,
    make_reference_env,
    reference_pixel_distances,
)


def _same_float32(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal dtype, shape and bits."""
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def _assert_same_info(info: dict, ref: dict, step: int) -> None:
    assert info.keys() == ref.keys(), step
    for key, value in ref.items():
        if isinstance(value, np.ndarray):
            assert _same_float32(info[key], value), (step, key, info[key], value)
        else:
            assert type(info[key]) is type(value) and info[key] == value, (step, key)


def _follow(base, rng: np.random.Generator, reckless: bool) -> np.ndarray:
    """A noisy track follower (tiles get visited); ``reckless`` swerves hard with more gas,
    over the curbs onto the grass and back."""
    x, y = base.car.hull.position
    track = np.asarray([(tx, ty) for _, _, tx, ty in base.track])
    i = int(np.argmin(np.sum((track - (x, y)) ** 2, axis=1)))
    dx, dy = track[(i + 4) % len(track)] - (x, y)
    heading = base.car.hull.angle
    lateral = (-math.sin(heading) * dy - math.cos(heading) * dx) / (math.hypot(dx, dy) + 1e-6)
    steer = -2.0 * lateral - 0.1 * base.car.hull.angularVelocity
    steer += rng.normal(0.0, 0.9 if reckless else 0.2)
    speed = math.hypot(*base.car.hull.linearVelocity)
    gas = rng.uniform(0.5, 1.0) if speed < (45.0 if reckless else 30.0) else 0.0
    brake = 0.5 if rng.random() < 0.03 else 0.0
    return np.array([np.clip(steer, -1.0, 1.0), gas, brake], dtype=np.float32)


def _compare_episode(env: gym.Env, ref: gym.Env, seed: int, steps: int, reckless: bool) -> dict:
    """Step both envs with the same actions; assert every output equal; count what was seen."""
    obs, info = env.reset(seed=seed)
    ref_obs, ref_info = ref.reset(seed=seed)
    assert np.array_equal(obs, ref_obs)
    _assert_same_info(info, ref_info, -1)
    rng = np.random.default_rng(seed)
    seen = {"warmup": 0, "offroad": 0, "partly_off": 0, "visited": 0, "steps": 0}
    for t in range(steps):
        action = _follow(ref.unwrapped, rng, reckless)
        out = env.step(action)
        ref_out = ref.step(action)
        assert out[0].dtype == np.uint8 and out[0].shape == (96, 96, 3)
        assert np.array_equal(out[0], ref_out[0]), f"frame {t} differs"
        assert out[1] == ref_out[1] and out[2] == ref_out[2] and out[3] == ref_out[3], t
        _assert_same_info(out[4], ref_out[4], t)
        seen["steps"] += 1
        seen["warmup"] += out[4]["warmup"]
        seen["offroad"] += out[4]["offroad"]
        seen["partly_off"] += 0 < out[4]["wheels_on_road"] < 4
        if out[2] or out[3]:
            break
    seen["visited"] = env.unwrapped.tile_visited_count
    assert seen["visited"] == ref.unwrapped.tile_visited_count
    return seen


@pytest.fixture(scope="module")
def envs():
    env, ref = make_env(EnvConfig(renderer="raster")), make_reference_env()
    yield env, ref
    env.close()
    ref.close()


@pytest.mark.parametrize(("seed", "steps", "reckless"), [(7, 320, False), (3, 300, True)])
def test_episodes_match_the_reference(envs, seed: int, steps: int, reckless: bool) -> None:
    seen = _compare_episode(*envs, seed, steps, reckless)
    assert seen["warmup"] >= 45  # the zoom-in, drawn with the moving playfield edge
    assert seen["visited"] > (5 if reckless else 40)  # recoloured tiles
    if reckless:  # on the grass, partly and wholly, and back
        assert seen["offroad"] > 50 and seen["partly_off"] > 20


def test_truncation_matches_the_reference() -> None:
    env = make_env(EnvConfig(renderer="raster", max_episode_steps=70))
    ref = make_reference_env(max_episode_steps=70)
    try:
        assert _compare_episode(env, ref, 5, 100, False)["steps"] == 70
    finally:
        env.close()
        ref.close()


def test_indicator_bars_above_the_panel_match(envs) -> None:
    """Extreme speed and wheel spin push the bars above the panel, onto the canvas."""
    env, ref = envs
    env.reset(seed=3)
    ref.reset(seed=3)
    for _ in range(55):
        env.step(np.array([0.0, 1.0, 0.0], np.float32))
        ref.step(np.array([0.0, 1.0, 0.0], np.float32))
    for base in (env.unwrapped, ref.unwrapped):
        base.car.hull.linearVelocity = (150.0, 190.0)  # speed bar ~100 px above the panel
        base.car.wheels[1].omega = 700.0
        base.car.wheels[3].omega = -300.0
        base.car.hull.angularVelocity = -40.0  # the horizontal bar off the window
    bars = env.unwrapped._indicator_polygons(1000, 800)
    assert sum(min(y for _, y in points) < 700 for points, _ in bars) >= 2  # above the panel
    frame = env.unwrapped._render("state_pixels")
    assert np.array_equal(frame, ref.unwrapped._render("state_pixels"))
    for _ in range(3):  # and while the physics winds down from there
        out = env.step(np.array([0.3, 0.0, 0.0], np.float32))
        ref_out = ref.step(np.array([0.3, 0.0, 0.0], np.float32))
        assert np.array_equal(out[0], ref_out[0])
        _assert_same_info(out[4], ref_out[4], 0)


@pytest.mark.parametrize("supersample", [1, 3, 4])
def test_other_supersample_factors_match(supersample: int) -> None:
    kw = {"continuous": True, "supersample": supersample, "max_episode_steps": 90}
    env, ref = gym.make(RASTER_CARRACING_ID, **kw), gym.make(REFERENCE_RASTER_ID, **kw)
    try:
        for s in (env, ref):
            s.reset(seed=supersample)
        rng = np.random.default_rng(0)
        for t in range(90):
            action = _follow(ref.unwrapped, rng, True)
            assert np.array_equal(env.step(action)[0], ref.step(action)[0]), t
    finally:
        env.close()
        ref.close()


def test_numpy_transforms_draw_the_same_frames(envs) -> None:
    """With its compiled kernels switched off (``compiled_drawing``), the same frames."""
    env, ref = envs
    base = env.unwrapped
    assert isinstance(base, RasterCarRacing)
    base.compiled_drawing = False
    try:
        _compare_episode(env, ref, 8, 120, True)
    finally:
        base.compiled_drawing = True


def _random_frames(rng: np.random.Generator, n: int) -> list[np.ndarray]:
    """Uniform noise; road and grass with random, anti-aliased edges; greenness right at the
    stopping level; all grass; all road."""
    frames = [rng.integers(0, 256, (96, 96, 3), dtype=np.uint8) for _ in range(n)]
    for _ in range(n):
        f = np.empty((96, 96, 3), np.uint8)
        f[...] = (102, 230, 102) if rng.random() < 0.5 else (102, 204, 102)
        cols = np.sort(rng.integers(0, 97, 2))
        rows = rng.integers(0, 70)
        f[rows:, cols[0] : cols[1]] = 102
        edge = rng.integers(0, 96, 40)
        f[rng.integers(0, 96, 40), edge, 1] = rng.integers(100, 231, 40)
        near = rng.integers(0, 96, (30, 2))
        f[near[:, 0], near[:, 1]] = np.stack(  # G - max(R, B) in 48..52
            [np.full(30, 100), 100 + rng.integers(48, 53, 30), rng.integers(0, 101, 30)], axis=1
        )
        frames.append(f)
    grass = np.empty((96, 96, 3), np.uint8)
    grass[...] = (102, 230, 102)
    road = np.full((96, 96, 3), 102, np.uint8)
    return [*frames, grass, road]


def test_pixel_distances_match_the_reference_on_random_frames() -> None:
    rng = np.random.default_rng(33)
    for frame in _random_frames(rng, 300):
        assert _same_float32(pixel_distances(frame), reference_pixel_distances(frame))
        assert _same_float32(costs._numpy_distances(frame), reference_pixel_distances(frame))


def test_pixel_distances_of_views_and_other_dtypes() -> None:
    rng = np.random.default_rng(4)
    big = rng.integers(0, 256, (96, 192, 3), dtype=np.uint8)
    view = big[:, ::2]  # not contiguous
    assert _same_float32(pixel_distances(view), reference_pixel_distances(view))
    as_int = big[:, :96].astype(np.int64)
    assert _same_float32(pixel_distances(as_int), reference_pixel_distances(as_int))
    with pytest.raises(ValueError, match="96, 96, 3"):
        pixel_distances(big)


def test_kernels_check_themselves_and_share_fast_render_s_constants() -> None:
    from safe_bc.tasks.carracing import fast_render, raster_kernels, ray_kernel

    assert ray_kernel.self_check() and raster_kernels.self_check()
    assert raster_kernels._SQRT2 == fast_render._SQRT2
    assert raster_kernels._SKIP_MARGIN == fast_render._SKIP_MARGIN


def test_the_switch_and_a_failed_check_keep_numpy(monkeypatch: pytest.MonkeyPatch) -> None:
    from safe_bc.tasks.carracing import compiled, raster_kernels

    monkeypatch.setenv(compiled.COMPILED_ENV, "0")
    monkeypatch.setattr(compiled, "_LOADED", {})
    assert compiled.load_kernels("ray_kernel") is None
    assert compiled.load_kernels("raster_kernels") is None
    monkeypatch.setenv(compiled.COMPILED_ENV, "1")
    monkeypatch.setattr(compiled, "_LOADED", {})
    monkeypatch.setattr(raster_kernels, "self_check", lambda: False)
    with pytest.warns(RuntimeWarning, match="raster_kernels disagree"):
        assert compiled.load_kernels("raster_kernels") is None
    assert compiled.load_kernels("ray_kernel") is not None


def test_costs_from_distances_is_the_clip_formula() -> None:
    """``costs_from_distances`` (two ufuncs) equals ``MAX_RANGE - np.clip(d, 0, MAX_RANGE)``,
    the formula the committed costs were made with, bit for bit, edge values included."""
    rng = np.random.default_rng(1)
    edges = np.array([0.0, -0.0, -1.0, 45.0, 66.0, 1e9, -np.inf, np.inf, np.nan, 44.999996])
    cases = [
        rng.uniform(-10.0, 80.0, (200, 3)),
        rng.uniform(-10.0, 80.0, (200, 3)).astype(np.float32),
        rng.choice(edges, (200, 3)),
        rng.choice(edges, (200, 3)).astype(np.float32),
        rng.integers(-5, 80, (50, 3)),
        np.array([3.0, -0.0, 70.0]),
    ]
    for d in cases:
        want = (costs.MAX_RANGE - np.clip(d, 0.0, costs.MAX_RANGE)).astype(np.float32)
        got = costs.costs_from_distances(d)
        assert got.dtype == want.dtype and got.shape == want.shape
        assert got.tobytes() == want.tobytes() or np.array_equal(got, want, equal_nan=True)
