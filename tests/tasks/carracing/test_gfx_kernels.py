"""The compiled gfxdraw ports must draw exactly what pygame-ce's gfxdraw draws."""

from __future__ import annotations

import numpy as np
import pygame
import pytest
from pygame import gfxdraw

from safe_bc.tasks.carracing import fast_render
from safe_bc.tasks.carracing.gfx_kernels import draw_polygons, matches_pygame


def _pixels(surf: pygame.Surface) -> np.ndarray:
    """``(H, W)`` RGB part of a 32-bit surface's pixels (a copy)."""
    return np.ascontiguousarray(pygame.surfarray.array2d(surf).astype(np.uint32).T) & 0xFFFFFF


def _draw_both(
    surf: pygame.Surface, points: list, color: tuple[int, int, int], top: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Draw ``points`` with pygame's two calls on ``surf`` and with the ports on a copy of its
    pixels (rows from ``top``); ``(ours, pygame's)``, each ``(H, W)`` RGB."""
    ours = _pixels(surf)
    gfxdraw.aapolygon(surf, points, color)
    gfxdraw.filled_polygon(surf, points, color)
    xy = np.asarray(points)
    packed = np.array([(color[0] << 16) | (color[1] << 8) | color[2]], np.int64)
    draw_polygons(ours, xy[None, :, 0], xy[None, :, 1], packed, top)
    return ours, _pixels(surf)


@pytest.mark.parametrize("size", [(1000, 800), (53, 41), (300, 7)])
def test_random_polygons_match_pygame(size: tuple[int, int]) -> None:
    """Random polygons of 3-6 vertices (convex or not), small to far larger than the surface
    (lines clipped on every side), over a random background: every pixel equal."""
    rng = np.random.default_rng(size[0])
    width, height = size
    for trial in range(60):
        surf = pygame.Surface(size)
        surf.fill(tuple(int(c) for c in rng.integers(0, 256, 3)))
        k = int(rng.integers(3, 7))
        scale = (30, 300, 3000)[trial % 3]
        points = rng.integers(-scale, scale + max(width, height), size=(k, 2)).tolist()
        color = tuple(int(c) for c in rng.integers(0, 256, 3))
        ours, theirs = _draw_both(surf, points, color)
        assert np.array_equal(ours, theirs), f"{size} trial {trial}: {points}"


def test_axis_aligned_and_degenerate_polygons_match_pygame() -> None:
    """Horizontal and vertical edges (gfxdraw draws them as opaque lines), a polygon one pixel
    high, one with repeated vertices, and one wholly outside the surface."""
    polygons = [
        [(10, 10), (90, 10), (90, 60), (10, 60)],
        [(5, 30), (70, 30), (70, 30), (5, 30)],
        [(20, 5), (20, 5), (60, 70), (21, 40)],
        [(-50, -40), (-10, -40), (-10, -5), (-50, -5)],
        [(40, -30), (140, 20), (40, 110), (-60, 20)],
    ]
    for points in polygons:
        surf = pygame.Surface((100, 80))
        surf.fill((30, 60, 90))
        ours, theirs = _draw_both(surf, points, (200, 100, 50))
        assert np.array_equal(ours, theirs), points


def test_rows_above_top_are_left_alone() -> None:
    """``top`` skips the rows that will be painted over; the others are still exact."""
    points = [(-30, -20), (120, 15), (60, 95), (-10, 70)]
    surf = pygame.Surface((100, 80))
    surf.fill((0, 0, 0))
    ours, expected = _draw_both(surf, points, (250, 250, 250), top=25)
    assert not ours[:25].any()
    assert expected[:25].any()
    assert np.array_equal(ours[25:], expected[25:])


def test_self_check_passes_and_the_renderer_uses_the_ports() -> None:
    """The once-per-process check holds here, so the default env draws with the ports (the
    frame-equality tests in ``test_fast_render.py`` then cover them end to end)."""
    assert matches_pygame(trials=30, seed=7)
    assert fast_render._compiled_draw() is draw_polygons


def test_a_failed_self_check_falls_back_to_pygame(monkeypatch: pytest.MonkeyPatch) -> None:
    """If the ports ever disagree with the installed pygame-ce, the renderer warns once and
    draws with pygame's own calls: frames stay identical."""
    from safe_bc.tasks.carracing import gfx_kernels

    monkeypatch.setattr(gfx_kernels, "matches_pygame", lambda: False)
    monkeypatch.setattr(fast_render._Compiled, "resolved", False)
    monkeypatch.setattr(fast_render._Compiled, "draw", None)
    with pytest.warns(RuntimeWarning, match="disagree"):
        assert fast_render._compiled_draw() is None
    env = fast_render.FastCarRacing()
    try:
        obs, _ = env.reset(seed=3)
        for _ in range(60):
            obs, *_ = env.step(np.array([0.0, 0.5, 0.0], np.float32))
    finally:
        env.close()
    assert obs.shape == (96, 96, 3)
    assert fast_render._compiled_draw() is None  # resolved once per process


def test_the_environment_variable_switches_the_ports_off(monkeypatch: pytest.MonkeyPatch) -> None:
    """``SAFE_BC_COMPILED_DRAWING=0`` keeps pygame's calls (and numba unimported)."""
    monkeypatch.setenv(fast_render.COMPILED_DRAWING_ENV, "0")
    monkeypatch.setattr(fast_render._Compiled, "resolved", False)
    monkeypatch.setattr(fast_render._Compiled, "draw", None)
    assert fast_render._compiled_draw() is None
    monkeypatch.setenv(fast_render.COMPILED_DRAWING_ENV, "1")
    monkeypatch.setattr(fast_render._Compiled, "resolved", False)
    assert fast_render._compiled_draw() is draw_polygons
