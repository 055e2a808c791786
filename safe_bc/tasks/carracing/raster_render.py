"""An approximate CarRacing-v3 renderer that draws the 96x96 state directly (opt-in).

``RasterCarRacing`` is :class:`~safe_bc.tasks.carracing.fast_render.FastCarRacing` (stock physics,
rewards, tracks and colours) whose ``state_pixels`` frame is rasterised with OpenCV on a small
canvas instead of drawn with pygame on a 1000x800 surface and smooth-scaled. The pygame path
is memory-bound: it fills ~1-2 million pixels per frame (background, grass squares of ~540 px,
road) and shrinks 700k of them, which the bit-identical renderer cannot avoid. Here the same
polygons (same culling, same float screen coordinates, same colours, same draw order) are
filled with ``cv2.fillPoly`` on a ``96 * supersample`` square canvas in the final (flipped,
non-uniformly scaled) frame coordinates and box-averaged down to 96x96 with
``cv2.INTER_AREA``. The indicator panel (the bottom 12 rows) is drawn the exact way, with
pygame on its own 1000x100 surface and smoothscale's two passes: agents read their speed off
the bar's anti-aliased edge, which the canvas would quantise to ``supersample`` levels per
pixel (its rows differ from stock's by at most 1, from where smoothscale's Y pass starts).

**Frames are not bit-identical to stock.** Road, grass and car edges differ by the
anti-aliasing (a box average of ``supersample**2`` samples instead of gfxdraw's anti-aliased
outline plus smoothscale's fixed-point filter), and so do the safety costs read off the
frames. ``benchmarks/render_accuracy.py`` and ``tune_jobs/compare/renderer*.py`` measure the frame
and cost differences and what they do to agents (``results/ablation/renderer/``); no committed
result uses this renderer. ``rgb_array``/``human`` renders are the exact ones of
``FastCarRacing``.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import pygame
from gymnasium.envs.box2d.car_dynamics import WHEEL_WHITE
from gymnasium.envs.box2d.car_racing import (
    STATE_H,
    STATE_W,
    WINDOW_H,
    WINDOW_W,
)

from safe_bc.tasks.carracing.fast_render import (
    _FIELD,
    _PANEL_ROWS,
    FastCarRacing,
    _rotation,
    _stripe_polygon,
    _surface_rgb,
)

__all__ = ["DEFAULT_SUPERSAMPLE", "RasterCarRacing"]

DEFAULT_SUPERSAMPLE = 2
"""Canvas side = ``96 * supersample``, chosen by ``benchmarks/render_accuracy.py``: the smallest
(fastest) factor whose safety distances stay within 10% of eps of the exact ones on average
(``results/ablation/renderer/``)."""
_PANEL_STATE_ROWS = STATE_H * _PANEL_ROWS // WINDOW_H  # 12: the indicator panel in the state
_SHIFT = 4  # fractional bits of the fixed-point vertices passed to cv2.fillPoly
_ONE = 1 << _SHIFT


class RasterCarRacing(FastCarRacing):
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
