"""FastCarRacing must produce exactly stock gymnasium's frames, rewards and terminations."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pygame
import pytest
from gymnasium.envs.box2d.car_racing import SCALE, ZOOM, CarRacing

from safe_bc.tasks.carracing.fast_render import FastCarRacing, _rotation


def _actions(seed: int, steps: int, reckless: bool) -> np.ndarray:
    """Seeded open-loop actions, shape ``(steps, 3)``: mostly gas with wandering steering.

    ``reckless`` steers harder with more gas, which takes the car over the grass.
    """
    rng = np.random.default_rng(seed)
    out = np.zeros((steps, 3), dtype=np.float32)
    steer = 0.0
    for t in range(steps):
        steer = 0.85 * steer + rng.normal(0.0, 0.45 if reckless else 0.15)
        steer = float(np.clip(steer, -1.0, 1.0))
        gas = rng.uniform(0.6, 1.0) if reckless else rng.uniform(0.2, 0.7)
        brake = 0.4 if rng.random() < 0.05 else 0.0
        out[t] = (steer, gas, brake)
    return out


def _driver(env: gym.Env, rng: np.random.Generator) -> np.ndarray:
    """Noisy track-following action for ``env``'s current state (the car mostly stays on the
    road, so tiles get visited and recoloured), shape ``(3,)``."""
    base = env.unwrapped
    x, y = base.car.hull.position
    track = np.asarray([(tx, ty) for _, _, tx, ty in base.track])
    i = int(np.argmin(np.sum((track - (x, y)) ** 2, axis=1)))
    dx, dy = track[(i + 4) % len(track)] - (x, y)
    heading = base.car.hull.angle
    lateral = (-math.sin(heading) * dy - math.cos(heading) * dx) / (math.hypot(dx, dy) + 1e-6)
    steer = -2.0 * lateral - 0.1 * base.car.hull.angularVelocity + rng.normal(0.0, 0.3)
    speed = math.hypot(*base.car.hull.linearVelocity)
    gas = rng.uniform(0.3, 0.9) if speed < 30.0 else 0.0
    return np.array([np.clip(steer, -1.0, 1.0), gas, 0.0], dtype=np.float32)


def _on_grass(env: gym.Env) -> bool:
    car = env.unwrapped.car
    return all(len(wheel.tiles) == 0 for wheel in car.wheels)


def _assert_same_episode(
    stock: gym.Env,
    fast: gym.Env,
    seed: int,
    actions: np.ndarray | int,
    reset_options: dict | None = None,
) -> dict[str, int]:
    """Step both envs through ``actions`` (or that many ``_driver`` steps); every
    observation, reward and termination flag must match."""
    obs_s, _ = stock.reset(seed=seed, options=reset_options)
    obs_f, _ = fast.reset(seed=seed, options=reset_options)
    assert obs_f.shape == obs_s.shape == (96, 96, 3)
    assert obs_f.dtype == obs_s.dtype == np.uint8
    assert np.array_equal(obs_s, obs_f), f"seed {seed}: reset frames differ"
    grass_steps = 0
    steps = 0
    rng = np.random.default_rng(seed)
    n_steps = actions if isinstance(actions, int) else len(actions)
    for t in range(n_steps):
        action = _driver(stock, rng) if isinstance(actions, int) else actions[t]
        obs_s, rew_s, term_s, trunc_s, _ = stock.step(action)
        obs_f, rew_f, term_f, trunc_f, _ = fast.step(action)
        if not np.array_equal(obs_s, obs_f):
            diff = np.argwhere(np.any(obs_s != obs_f, axis=-1))
            pytest.fail(
                f"seed {seed} step {t}: {len(diff)} pixels differ, first {diff[:3].tolist()}"
            )
        assert rew_s == rew_f, f"seed {seed} step {t}: reward {rew_s} != {rew_f}"
        assert (term_s, trunc_s) == (term_f, trunc_f), f"seed {seed} step {t}"
        grass_steps += _on_grass(stock)
        steps += 1
        if term_s or trunc_s:
            break
    return {
        "steps": steps,
        "grass_steps": grass_steps,
        "visited": stock.unwrapped.tile_visited_count,
    }


def test_frames_identical_to_stock() -> None:
    """Three seeds on one env pair (the track cache is rebuilt per reset), covering the zoom-in,
    visited (recoloured) tiles, grass, the indicator bar and the score digits."""
    stock = gym.make("CarRacing-v3")
    fast = FastCarRacing()
    try:
        stats = [
            _assert_same_episode(stock, fast, 0, 250),  # track following, noisy
            _assert_same_episode(stock, fast, 1, _actions(1, 200, reckless=False)),
            _assert_same_episode(stock, fast, 2, _actions(2, 200, reckless=True)),  # grass
        ]
    finally:
        stock.close()
        fast.close()
    assert all(s["steps"] > 60 for s in stats), stats  # past the ~50-step zoom-in
    assert stats[0]["visited"] > 20, stats  # tiles recoloured when visited
    assert sum(s["grass_steps"] for s in stats) > 0, stats


def test_indicator_overflow_uses_stock_composition() -> None:
    """Huge wheel spin pushes the ABS bars above the indicator panel: still identical."""
    stock = CarRacing()
    fast = FastCarRacing()
    try:
        for env in (stock, fast):
            env.reset(seed=4)
        for t, action in enumerate(_actions(4, 60, reckless=False)):
            if t in (20, 40):
                for env in (stock, fast):
                    for wheel in env.car.wheels:
                        wheel.omega = 700.0 if t == 20 else -900.0
            obs_s, rew_s, *_ = stock.step(action)
            obs_f, rew_f, *_ = fast.step(action)
            assert np.array_equal(obs_s, obs_f), f"step {t}"
            assert rew_s == rew_f
    finally:
        stock.close()
        fast.close()


def test_domain_randomize_identical() -> None:
    stock = CarRacing(domain_randomize=True)
    fast = FastCarRacing(domain_randomize=True)
    try:
        _assert_same_episode(stock, fast, 11, _actions(11, 80, reckless=False))
        # a new random palette on the next reset, and none when randomize=False
        _assert_same_episode(stock, fast, 12, _actions(12, 30, reckless=True))
        _assert_same_episode(
            stock, fast, 13, _actions(13, 30, reckless=False), reset_options={"randomize": False}
        )
    finally:
        stock.close()
        fast.close()


def test_rgb_array_render_identical() -> None:
    stock = CarRacing(render_mode="rgb_array")
    fast = FastCarRacing(render_mode="rgb_array")
    try:
        for env in (stock, fast):
            env.reset(seed=5)
        for t, action in enumerate(_actions(5, 70, reckless=False)):
            obs_s, *_ = stock.step(action)
            obs_f, *_ = fast.step(action)
            assert np.array_equal(obs_s, obs_f), f"step {t}"
            if t % 10 == 0 or t == 69:
                frame_s, frame_f = stock.render(), fast.render()
                assert frame_f.shape == frame_s.shape == (400, 600, 3)
                assert np.array_equal(frame_s, frame_f), f"rgb_array frame at step {t}"
    finally:
        stock.close()
        fast.close()


def test_human_mode_runs_and_matches(monkeypatch: pytest.MonkeyPatch) -> None:
    """Human mode (headless SDL) keeps working; closing quits pygame, which must not break the
    cached font of a later env."""
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    stock = CarRacing(render_mode="human")
    fast = FastCarRacing(render_mode="human")
    try:
        for env in (stock, fast):
            env.reset(seed=6)
        for action in _actions(6, 8, reckless=False):
            obs_s, *_ = stock.step(action)
            obs_f, *_ = fast.step(action)
            assert np.array_equal(obs_s, obs_f)
        assert fast.surf is not None and fast.surf.get_size() == (1000, 800)
    finally:
        stock.close()
        fast.close()  # pygame.quit(): fonts and display are gone now
    stock, fast = CarRacing(), FastCarRacing()
    try:
        _assert_same_episode(stock, fast, 7, _actions(7, 5, reckless=False))
    finally:
        stock.close()
        fast.close()


def test_font_reloaded_after_pygame_restart() -> None:
    """Another env's ``close()`` may quit pygame (unloading fonts) and something else re-init
    it between two of our frames; the cached font must not be reused then."""
    stock, fast = CarRacing(), FastCarRacing()
    try:
        for env in (stock, fast):
            env.reset(seed=8)
        for t, action in enumerate(_actions(8, 12, reckless=False)):
            if t == 6:
                pygame.quit()
                pygame.font.init()
            obs_s, *_ = stock.step(action)
            obs_f, *_ = fast.step(action)
            assert np.array_equal(obs_s, obs_f), f"step {t}"
    finally:
        stock.close()
        fast.close()


def test_rotation_matches_pygame_vector2() -> None:
    """The numpy transform relies on reproducing ``Vector2.rotate_rad`` bit for bit."""
    rng = np.random.default_rng(0)
    angles = [*rng.uniform(-20.0, 20.0, 400)]
    angles += [k * math.pi / 2 + d for k in range(-5, 6) for d in (0.0, 3e-7, -3e-7, 2e-6, -2e-6)]
    points = rng.uniform(-400.0, 400.0, (8, 2))
    for angle in angles:
        c, s = _rotation(angle)
        rx = c * points[:, 0] - s * points[:, 1]
        ry = s * points[:, 0] + c * points[:, 1]
        for (x, y), ex, ey in zip(points.tolist(), rx.tolist(), ry.tolist(), strict=True):
            v = pygame.math.Vector2((x, y)).rotate_rad(angle)
            assert (v[0], v[1]) == (ex, ey), angle


def test_smoothscale_is_separable_and_flip_commutes_with_x_pass() -> None:
    """The frame composition relies on pygame's smoothscale shrinking X (per row) then Y."""
    rng = np.random.default_rng(1)
    for _ in range(3):
        surf = pygame.Surface((1000, 800))
        pygame.surfarray.blit_array(surf, rng.integers(0, 256, (1000, 800, 3), dtype=np.uint8))
        expected = pygame.transform.smoothscale(pygame.transform.flip(surf, False, True), (96, 96))
        x_pass = pygame.transform.smoothscale(surf, (96, 800))
        composed = pygame.transform.smoothscale(
            pygame.transform.flip(x_pass, False, True), (96, 96)
        )
        assert np.array_equal(
            pygame.surfarray.array3d(expected), pygame.surfarray.array3d(composed)
        )


def _teleport(env: CarRacing, x: float, y: float) -> None:
    """Move the car (hull and wheels, keeping their offsets) so the hull sits at ``(x, y)``."""
    car = env.unwrapped.car
    hx, hy = car.hull.position
    for body in [car.hull, *car.wheels]:
        bx, by = body.position
        body.position = (bx - hx + x, by - hy + y)


def test_frames_identical_near_the_playfield_edge() -> None:
    """Near the edge of the playfield the background square no longer covers the window:
    the cheap cover test must fall back to the exact one (and to gfxdraw) there."""
    from gymnasium.envs.box2d.car_racing import PLAYFIELD

    stock, fast = CarRacing(), FastCarRacing()
    try:
        for env in (stock, fast):
            env.reset(seed=9)
        actions = _actions(9, 105, reckless=False)
        covered = []
        for t, action in enumerate(actions):
            if t in (55, 75, 90):  # after the zoom-in; then two more spots
                x, y = {55: (PLAYFIELD - 30.0, 0.0), 75: (-PLAYFIELD + 60.0, PLAYFIELD - 20.0)}.get(
                    t, (0.0, -PLAYFIELD + 45.0)
                )
                for env in (stock, fast):
                    _teleport(env, x, y)
            obs_s, rew_s, term_s, *_ = stock.step(action)
            obs_f, rew_f, term_f, *_ = fast.step(action)
            assert np.array_equal(obs_s, obs_f), f"step {t}"
            assert (rew_s, term_s) == (rew_f, term_f)
            covered.append(fast._field_covers_window(ZOOM * SCALE))
            if term_s:
                break
        assert t > 60 and not all(covered[55:])
    finally:
        stock.close()
        fast.close()


def test_cheap_cover_test_implies_the_exact_one() -> None:
    """``_field_covers_window`` (car far from the playfield's edges) never says yes where
    ``_covers_window`` (the exact test on gfxdraw's integer vertices) says no."""
    from gymnasium.envs.box2d.car_racing import PLAYFIELD, WINDOW_H, WINDOW_W

    from safe_bc.tasks.carracing.fast_render import _FIELD

    env = FastCarRacing()
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    yes = 0
    try:
        for _ in range(3000):
            x, y = rng.uniform(-PLAYFIELD, PLAYFIELD, 2)
            angle = float(rng.uniform(-10.0, 10.0))
            zoom = float(rng.choice([ZOOM * SCALE, rng.uniform(0.6, ZOOM * SCALE)]))
            env.car.hull.position = (float(x), float(y))
            hx, hy = env.car.hull.position
            trans = pygame.math.Vector2((-hx * zoom, -hy * zoom)).rotate_rad(-env.car.hull.angle)
            tx, ty = WINDOW_W / 2 + trans[0], WINDOW_H / 4 + trans[1]
            c, s = _rotation(-env.car.hull.angle)
            poly = [((c * a - s * b) * zoom + tx, (s * a + c * b) * zoom + ty) for a, b in _FIELD]
            env.car.hull.angle = angle
            if env._field_covers_window(zoom):
                yes += 1
                assert env._covers_window([p[0] for p in poly], [p[1] for p in poly])
    finally:
        env.close()
    assert 100 < yes < 3000


def test_near_polygons_include_every_polygon_that_could_be_drawn() -> None:
    """The world-space disc pre-selection keeps every polygon that passes the exact
    per-vertex test over all polygons, at any zoom, rotation and translation."""
    from gymnasium.envs.box2d.car_racing import MAX_SHAPE_DIM, WINDOW_H, WINDOW_W

    from safe_bc.tasks.carracing.fast_render import _SKIP_MARGIN, _to_screen

    env = FastCarRacing()
    env.reset(seed=1)
    env._sync_polygons()
    rng = np.random.default_rng(1)
    drawn_total = 0
    try:
        for _ in range(300):
            zoom = float(rng.choice([ZOOM * SCALE, rng.uniform(0.5, ZOOM * SCALE)]))
            angle = float(rng.uniform(-10.0, 10.0))
            i = int(rng.integers(len(env.track)))
            _, _, x, y = env.track[i]
            trans = pygame.math.Vector2((-x * zoom, -y * zoom)).rotate_rad(angle)
            translation = (WINDOW_W / 2 + trans[0], WINDOW_H / 4 + trans[1])
            for top in (0, 100):
                near = env._near_polygons(zoom, translation, angle, top)
                px, py = _to_screen(env._poly_xy, zoom, translation, angle)
                inside = (
                    (px >= -MAX_SHAPE_DIM)
                    & (px <= WINDOW_W + MAX_SHAPE_DIM)
                    & (py >= -MAX_SHAPE_DIM)
                    & (py <= WINDOW_H + MAX_SHAPE_DIM)
                ).any(axis=1)
                touches = (
                    inside
                    & (px.max(axis=1) >= -_SKIP_MARGIN)
                    & (px.min(axis=1) <= WINDOW_W + _SKIP_MARGIN)
                    & (py.max(axis=1) >= top - _SKIP_MARGIN)
                    & (py.min(axis=1) <= WINDOW_H + _SKIP_MARGIN)
                )
                drawn = np.flatnonzero(touches)
                drawn_total += drawn.size
                assert set(drawn.tolist()) <= set(near.tolist())
                assert np.all(np.diff(near) > 0)
    finally:
        env.close()
    assert drawn_total > 1000
