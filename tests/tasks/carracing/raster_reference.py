"""The raster renderer and the pixel safety distances as they were before they were optimised (the
first raster renderer; docs/history.md names its revision): the method bodies of
``RasterCarRacing`` and ``pixel_distances`` copied verbatim, so that ``test_raster_identity.py``
can prove the optimised env draws the very same frames and computes the very same costs
(``results/ablation/renderer/`` describes these).

Do not edit the copied bodies; they are the definition the optimised code is held to.
"""

from __future__ import annotations

from typing import Any

import cv2
import gymnasium as gym
import numpy as np
import pygame
from gymnasium.envs.box2d.car_dynamics import WHEEL_WHITE
from gymnasium.envs.box2d.car_racing import (
    STATE_H,
    STATE_W,
    WINDOW_H,
    WINDOW_W,
)

from safe_bc.tasks.carracing.costs import costs_from_distances
from safe_bc.tasks.carracing.fast_render import (
    _FIELD,
    _PANEL_ROWS,
    FastCarRacing,
    _rotation,
    _stripe_polygon,
    _surface_rgb,
)
from safe_bc.tasks.carracing.wrapper import ZOOM_END_T, CarRacingSafety

REFERENCE_RASTER_ID = "safe_bc_test/CarRacingRasterReference-v3"
"""gymnasium id of :class:`ReferenceRasterCarRacing` (registered like the raster env's)."""

_PANEL_STATE_ROWS = STATE_H * _PANEL_ROWS // WINDOW_H  # 12: the indicator panel in the state
_SHIFT = 4  # fractional bits of the fixed-point vertices passed to cv2.fillPoly
_ONE = 1 << _SHIFT
DEFAULT_SUPERSAMPLE = 2  # raster_render.DEFAULT_SUPERSAMPLE then
# costs.py's ray geometry then
CAR_ROWS = slice(66, 78)
CAR_COLS = slice(45, 51)
LEFT_START, RIGHT_START, FRONT_START = 44, 51, 65
GRASS_LEVEL = 0.5


class ReferenceRasterCarRacing(FastCarRacing):
    """gymnasium ``CarRacing`` whose 96x96 state is rasterised directly (approximate frames).

    Args:
        supersample: canvas side in multiples of 96; the frame is the canvas box-averaged.
        **kwargs: ``CarRacing``'s own arguments.
    """

    def __init__(self, *args: Any, supersample: int = DEFAULT_SUPERSAMPLE, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if not isinstance(supersample, int) or not 1 <= supersample <= 16:
            raise ValueError(f"supersample must be an int in [1, 16], got {supersample!r}")
        self.supersample = supersample
        side = STATE_W * supersample
        self._canvas = np.zeros((STATE_H * supersample, side, 3), np.uint8)
        # screen (unflipped 1000x800) -> canvas fixed point: X = x * sx - 0.5, Y = (H - y) * sy
        # - 0.5 (cv2 puts pixel centres on integers; pygame's pixel j covers [j, j + 1))
        self._sx = side / WINDOW_W
        self._sy = STATE_H * supersample / WINDOW_H
        self._bg_canvas: np.ndarray | None = None
        self._panel_state: pygame.Surface | None = None
        self._bg_key: tuple[int, ...] = ()
        halvings = 0
        while supersample % (2 ** (halvings + 1)) == 0:
            halvings += 1
        self._halvings = halvings  # 2x2 INTER_AREA steps before the last resize

    # ------------------------------------------------------------------ geometry
    def _canvas_points(self, px: np.ndarray, py: np.ndarray) -> np.ndarray:
        """Unflipped screen coordinates ``(..., K)`` -> ``(..., K, 2)`` int32 fixed point."""
        x = (px * self._sx - 0.5) * _ONE
        y = ((WINDOW_H - py) * self._sy - 0.5) * _ONE
        return np.stack([x, y], axis=-1).round().astype(np.int32)

    def _fill(self, points: np.ndarray, color: Any) -> None:
        cv2.fillPoly(self._canvas, [points], _bgr_free(color), cv2.LINE_8, _SHIFT)

    # ------------------------------------------------------------------ frame
    def _render(self, mode: str) -> Any:
        if mode != "state_pixels" or "t" not in self.__dict__:
            return super()._render(mode)
        self._ensure_font()  # the score digits
        zoom, trans, angle = self._view()
        c, s = _rotation(angle)
        indicators = self._indicator_polygons(WINDOW_W, WINDOW_H)
        self._draw_field(zoom, trans, c, s)
        self._draw_polygons(zoom, trans, angle)
        self._draw_car_raster(zoom, trans, c, s)
        self._draw_indicators(indicators)
        frame = self._canvas
        for _ in range(
            self._halvings
        ):  # 2x2 averages (cv2's fast path; each rounds), then the rest
            frame = cv2.resize(
                frame, (frame.shape[1] // 2, frame.shape[0] // 2), interpolation=cv2.INTER_AREA
            )
        if frame.shape[0] != STATE_H:
            frame = cv2.resize(frame, (STATE_W, STATE_H), interpolation=cv2.INTER_AREA)
        frame = frame.copy() if frame is self._canvas else frame  # a new array every step
        frame[STATE_H - _PANEL_STATE_ROWS :] = self._exact_panel(indicators)
        return frame

    def _exact_panel(self, indicators: list[tuple[list, tuple[int, int, int]]]) -> np.ndarray:
        """The bottom ``_PANEL_STATE_ROWS`` rows drawn the exact way (pygame polygons and text on
        the 1000x100 panel, smoothscale's X then Y pass): ``(12, 96, 3)`` uint8.

        Agents read their speed off the indicator bar's anti-aliased top edge; on the canvas
        it takes only ``supersample`` levels per pixel, here smoothscale's fine ones.
        """
        bufs = self._buffers()
        panel = bufs.panel
        self._draw_panel(panel, indicators)
        self._draw_score(panel)
        if self._panel_state is None or self._panel_state.get_bitsize() != panel.get_bitsize():
            self._panel_state = pygame.Surface((STATE_W, _PANEL_STATE_ROWS), 0, panel)
        pygame.transform.smoothscale(bufs.panel_rows, (STATE_W, _PANEL_ROWS), bufs.panel_x)
        pygame.transform.smoothscale(bufs.panel_x, (STATE_W, _PANEL_STATE_ROWS), self._panel_state)
        return _surface_rgb(self._panel_state)

    def _draw_field(self, zoom: float, trans: tuple[float, float], c: float, s: float) -> None:
        """Stock's background square: a copy of a plain canvas when it covers the window."""
        key = tuple(int(v) for v in self.bg_color)
        if self._bg_canvas is None or self._bg_key != key:
            self._bg_canvas = np.empty_like(self._canvas)
            self._bg_canvas[:] = key
            self._bg_key = key
        if self._field_covers_window(zoom):
            np.copyto(self._canvas, self._bg_canvas)
            return
        self._canvas.fill(0)
        field = np.asarray(_FIELD, np.float64)
        px = (c * field[:, 0] - s * field[:, 1]) * zoom + trans[0]
        py = (s * field[:, 0] + c * field[:, 1]) * zoom + trans[1]
        self._fill(self._canvas_points(px, py), self.bg_color)

    def _draw_polygons(self, zoom: float, trans: tuple[float, float], angle: float) -> None:
        """Stock's grass squares and road polygons that reach the frame, in stock's order
        (the exact renderer's culling; rows under the panel are drawn by ``_exact_panel``)."""
        px, py, colors = self._visible_polygons(zoom, trans, angle, _PANEL_ROWS)
        canvas = self._canvas
        for poly, color in zip(self._canvas_points(px, py), colors, strict=True):
            cv2.fillPoly(canvas, [poly], _bgr_free(color), cv2.LINE_8, _SHIFT)

    def _draw_car_raster(self, zoom: float, trans: tuple[float, float], c: float, s: float) -> None:
        """The hull and wheels (and the wheels' white stripes), as stock's ``Car.draw``.

        Every vertex is moved to the world with its body's position and angle in one numpy
        expression (stock lets Box2D transform them one by one).
        """
        car = self.car
        assert car is not None
        if self._car_src is not car:
            self._car_shapes = [
                (obj, [list(f.shape.vertices) for f in obj.fixtures]) for obj in car.drawlist
            ]
            local, body, sizes, colors = [], [], [], []
            for b, (obj, shapes) in enumerate(self._car_shapes):
                for vertices in shapes:
                    local += vertices
                    body += [b] * len(vertices)
                    sizes.append(len(vertices))
                    colors.append([int(v * 255) for v in obj.color])
            self._car_local = np.asarray(local, np.float64)
            self._car_body = np.asarray(body)
            self._car_split = np.cumsum(sizes)[:-1]
            self._car_colors = colors
            self._car_src = car
        bodies = [obj for obj, _ in self._car_shapes]
        pos = np.asarray([tuple(obj.position) for obj in bodies], np.float64)
        ang = np.asarray([obj.angle for obj in bodies], np.float64)
        polys, colors = [self._car_local], list(self._car_colors)
        index = [self._car_body]
        for b, obj in enumerate(bodies):
            if "phase" not in obj.__dict__:  # wheels have a phase, the hull has not
                continue
            stripe = _stripe_polygon(obj.phase)
            if stripe is None:
                continue
            polys.append(np.asarray(stripe, np.float64))
            index.append(np.full(4, b))
            colors.append(list(WHEEL_WHITE))
        local = np.concatenate(polys)
        b = np.concatenate(index)
        bc, bs = np.cos(ang)[b], np.sin(ang)[b]
        wx = bc * local[:, 0] - bs * local[:, 1] + pos[b, 0]
        wy = bs * local[:, 0] + bc * local[:, 1] + pos[b, 1]
        px = (c * wx - s * wy) * zoom + trans[0]
        py = (s * wx + c * wy) * zoom + trans[1]
        pts = self._canvas_points(px, py)
        n_stripes = len(colors) - len(self._car_colors)
        split = np.concatenate([self._car_split, len(self._car_local) + 4 * np.arange(n_stripes)])
        canvas = self._canvas
        for poly, color in zip(np.split(pts, split), colors, strict=True):
            cv2.fillPoly(canvas, [poly], color, cv2.LINE_8, _SHIFT)

    def _draw_indicators(self, indicators: list[tuple[list, tuple[int, int, int]]]) -> None:
        """The indicator bars on the canvas, for the rare frames where one reaches above the
        panel (its rows are replaced by ``_exact_panel``)."""
        if not indicators:
            return
        p = np.asarray([points for points, _ in indicators], np.float64)  # (K, 4, 2)
        # already flipped: _canvas_points maps (H - y) to canvas row y * sy
        pts = self._canvas_points(p[..., 0], WINDOW_H - p[..., 1])
        for poly, (_, color) in zip(pts, indicators, strict=True):
            cv2.fillPoly(self._canvas, [poly], color, cv2.LINE_8, _SHIFT)


def _bgr_free(color: Any) -> list[int]:
    """A colour as the int list cv2 wants (channels stay in RGB order: the canvas is RGB)."""
    return [int(v) for v in color]


def reference_pixel_distances(frame: np.ndarray) -> np.ndarray:
    """Road pixels between the car and the grass, to the left, front and right.

    Args:
        frame: ``(96, 96, 3) uint8`` CarRacing state (after the zoom-in phase).

    Returns:
        ``(3,) float32`` distances in pixels, ordered as :data:`SAFETY_DIMS`.
    """
    if frame.shape != (96, 96, 3):
        raise ValueError(f"expected a (96, 96, 3) CarRacing frame, got shape {frame.shape}")
    # greenness of the ray pixels only (the same float32 operations as ``greenness``), every
    # ray in one row of ``green``; a ray's cumulative sum runs along its own row, so each
    # distance is the one ``_ray_distance`` gives for that ray alone
    f = frame[: CAR_ROWS.stop].astype(np.int16)  # rows below the car hold no ray
    excess = (f[..., 1] - np.maximum(f[..., 0], f[..., 2])).take(_RAY_FLAT)
    green = excess.astype(np.float32) / 100.0
    np.minimum(np.maximum(green, 0.0, out=green), 1.0, out=green)  # == np.clip(.., 0, 1)
    green[_RAY_PAD] = 1.0
    csum = np.cumsum(1.0 - green, axis=1)
    hit = green >= GRASS_LEVEL
    first = np.where(hit.any(axis=1), hit.argmax(axis=1), green.shape[1] - 1)
    d = csum.take(_RAY_BASE + first)
    n = CAR_ROWS.stop - CAR_ROWS.start
    left = d[:n].mean()
    right = d[n : 2 * n].mean()
    front = d[2 * n :].mean()
    return np.array([left, front, right], np.float32)


def _ray_pixels() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel indices of every ray, one ray per row, pixel 0 next to the car.

    Rows: the left rays of ``CAR_ROWS``, then their right rays, then the front rays of
    ``CAR_COLS``; ``(R, L)`` row indices, column indices and a pad mask. Side rays (45 px) are
    padded to the front rays' 66 px with pixels that count as grass: ``_ray_distance`` stops
    there at the latest and adds a road fraction of exactly 0, so a side ray's distance is the
    one of its unpadded pixels.
    """
    length = FRONT_START + 1
    rows, cols, pad = [], [], []
    for direction in (-1, 1):
        first = LEFT_START if direction < 0 else RIGHT_START
        n = first + 1 if direction < 0 else 96 - first
        for r in range(CAR_ROWS.start, CAR_ROWS.stop):
            rows.append([r] * length)
            cols.append([first + direction * min(i, n - 1) for i in range(length)])
            pad.append([i >= n for i in range(length)])
    for c in range(CAR_COLS.start, CAR_COLS.stop):
        rows.append([FRONT_START - i for i in range(length)])
        cols.append([c] * length)
        pad.append([False] * length)
    return np.asarray(rows), np.asarray(cols), np.asarray(pad)


_RAY_ROWS, _RAY_COLS, _RAY_PAD = _ray_pixels()
_RAY_FLAT = _RAY_ROWS * 96 + _RAY_COLS  # (R, L) flat pixel index into a (rows, 96) plane
_RAY_BASE = np.arange(len(_RAY_ROWS)) * _RAY_ROWS.shape[1]  # flat index of each ray's pixel 0


class ReferenceCarRacingSafety(CarRacingSafety):
    """``CarRacingSafety`` whose distances are :func:`reference_pixel_distances`."""

    def _augment(self, obs: np.ndarray, info: dict[str, Any]) -> dict[str, Any]:
        inner = self.env.unwrapped
        distances = reference_pixel_distances(obs)
        info = dict(info)
        info["safety"] = distances
        info["cost"] = costs_from_distances(distances)
        info["warmup"] = bool(inner.t < ZOOM_END_T - 1e-6)
        on_road = sum(1 for w in inner.car.wheels if len(w.tiles) > 0)
        info["offroad"] = on_road == 0
        info["wheels_on_road"] = on_road
        return info


def make_reference_env(max_episode_steps: int | None = None) -> gym.Env:
    """What ``make_env(EnvConfig(renderer="raster"))`` built before the optimisation: the
    reference renderer through ``gym.make``'s wrappers, with the reference costs."""
    from safe_bc.tasks.info import InfoContract

    if REFERENCE_RASTER_ID not in gym.registry:
        gym.register(
            id=REFERENCE_RASTER_ID,
            entry_point=ReferenceRasterCarRacing,
            max_episode_steps=1000,
            reward_threshold=900,
        )
    kwargs = {} if max_episode_steps is None else {"max_episode_steps": max_episode_steps}
    env = gym.make(REFERENCE_RASTER_ID, continuous=True, domain_randomize=False, **kwargs)
    return InfoContract(ReferenceCarRacingSafety(env))
