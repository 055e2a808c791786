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
frames. ``scripts/render_accuracy.py`` and ``tune_jobs/compare/renderer.py`` measure the frame
and cost differences and what they do to agents (``results/ablation/renderer/``); no committed
result uses this renderer. ``rgb_array``/``human`` renders are the exact ones of
``FastCarRacing``.

**Per-step cost.** The ~35 ``cv2.fillPoly`` calls of a frame are a minor part of a step; numpy's
per-call overhead on small arrays (moving the polygons' vertices) and the panel were most of
it. With numba (:mod:`.raster_kernels`, switched as :mod:`.compiled` says) one call culls
the track polygons and maps the kept ones to the canvas and one maps the car's, with the numpy
expressions' float operations (the same fixed-point vertices); the fills read prebuilt views of
the kernels' output. Indicator bars that stay inside the panel are not filled on the canvas
(the panel's rows are replaced); the panel's black background is painted (a black polygon,
as stock's) only over the rows that the bars and the score reach, and only those rows go
through smoothscale's X pass (it works row by row; a black row shrinks to black).
``compiled_drawing = False`` (or no numba) runs the numpy transforms. The frames are the same
either way, and the same as the implementation that ``results/ablation/renderer/`` measured
(``tests/tasks/carracing/test_raster_identity.py``).
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

from safe_bc.tasks.carracing.compiled import load_kernels
from safe_bc.tasks.carracing.fast_render import (
    _FIELD,
    _GRASS,
    _PANEL_ROWS,
    _PANEL_TOP,
    FastCarRacing,
    _near_disc,
    _rotation,
    _stripe_polygon,
    _surface_rgb,
)

__all__ = ["DEFAULT_SUPERSAMPLE", "RasterCarRacing"]

DEFAULT_SUPERSAMPLE = 2
"""Canvas side = ``96 * supersample``, chosen by ``scripts/render_accuracy.py``: the smallest
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

    compiled_drawing = True
    """Cull and move the vertices with :mod:`.raster_kernels` where they are available (the
    frames are the same either way; ``False``: numpy, for benchmarks and tests)."""

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
        self._bg_key: tuple[Any, ...] = ()  # bg_color's values the plain canvas was made of
        halvings = 0
        while supersample % (2 ** (halvings + 1)) == 0:
            halvings += 1
        self._halvings = halvings  # 2x2 INTER_AREA steps before the last resize
        # the compiled path's buffers: (poly_xy they were made for, vertices, indices, views)
        self._track_buf: (
            tuple[np.ndarray, np.ndarray, np.ndarray, list[list[np.ndarray]]] | None
        ) = None
        self._car_buf: _CarBuffers | None = None
        self._view_buf = np.empty(10)  # raster_kernels' camera vector
        self._band_surfaces: dict[tuple[int, int], tuple[pygame.Surface, pygame.Surface]] = {}
        self._band_bufs: Any = None  # the _Buffers the band subsurfaces belong to

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
        kernels = _raster_kernels() if self.compiled_drawing else None
        view = None if kernels is None else self._camera(zoom, trans, c, s)
        if view is None or not self._draw_track_compiled(kernels, view):
            self._draw_polygons(zoom, trans, angle)
        if view is None or not self._draw_car_compiled(kernels, view):
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
        text, text_rect = self._score_placement()
        # the panel rows anything but black can reach: the bars' rows (pygame truncates their
        # vertices to int and fills the rows in between, ends included) and the score's
        top, bottom = text_rect.top, text_rect.bottom
        ys = [y for points, _ in indicators for _, y in points]
        if ys:  # int() is monotonic: the extreme rows are those of the extreme vertices
            top = min(top, int(min(ys)))
            bottom = max(bottom, int(max(ys)) + 1)
        top = min(max(top - 1, _PANEL_TOP), WINDOW_H)
        bottom = max(min(bottom + 1, WINDOW_H), top)
        # stock's black polygon paints all the panel's rows: the band's are painted here the
        # same way (a black polygon over rows top..bottom - 1; Surface.fill would be the same
        # pixels, but SDL's streaming stores leave them out of the cache for what follows)
        _black_rows(panel, top, bottom, WINDOW_W)
        draw_polygon = pygame.draw.polygon
        for points, color in indicators:
            draw_polygon(panel, color, points)
        panel.blit(text, text_rect)
        if self._panel_state is None or self._panel_state.get_bitsize() != panel.get_bitsize():
            self._panel_state = pygame.Surface((STATE_W, _PANEL_STATE_ROWS), 0, panel)
        # smoothscale's X pass shrinks each row on its own and a black row to black (0): only
        # the band's rows are shrunk, the others are made black
        panel_x = bufs.panel_x
        _black_rows(panel_x, 0, top - _PANEL_TOP, STATE_W)
        _black_rows(panel_x, bottom - _PANEL_TOP, _PANEL_ROWS, STATE_W)
        if bottom > top:
            band_rows, band_x = self._band(bufs, top, bottom)
            pygame.transform.smoothscale(band_rows, (STATE_W, bottom - top), band_x)
        pygame.transform.smoothscale(bufs.panel_x, (STATE_W, _PANEL_STATE_ROWS), self._panel_state)
        return _surface_rgb(self._panel_state)

    def _band(self, bufs: Any, top: int, bottom: int) -> tuple[pygame.Surface, pygame.Surface]:
        """Rows ``top:bottom`` of the panel and the same rows of its X-shrunk copy (cached
        subsurfaces of ``bufs``)."""
        if self._band_bufs is not bufs:
            self._band_surfaces = {}
            self._band_bufs = bufs
        pair = self._band_surfaces.get((top, bottom))
        if pair is None:
            rows = bufs.panel.subsurface((0, top, WINDOW_W, bottom - top))
            shrunk = bufs.panel_x.subsurface((0, top - _PANEL_TOP, STATE_W, bottom - top))
            pair = self._band_surfaces[(top, bottom)] = (rows, shrunk)
        return pair

    def _draw_field(self, zoom: float, trans: tuple[float, float], c: float, s: float) -> None:
        """Stock's background square: a copy of a plain canvas when it covers the window."""
        bg = self.bg_color
        key = tuple(bg.tolist() if isinstance(bg, np.ndarray) else bg)
        if self._bg_canvas is None or self._bg_key != key:
            self._bg_canvas = np.empty_like(self._canvas)
            self._bg_canvas[:] = _bgr_free(key)
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

    def _camera(self, zoom: float, trans: tuple[float, float], c: float, s: float) -> np.ndarray:
        """:mod:`.raster_kernels`' camera vector ``[c, s, zoom, tx, ty, kx, ky, reach, sx,
        sy]`` (the disc of ``FastCarRacing._near_polygons`` for the rows above the panel)."""
        view = self._view_buf
        kx, ky, reach = _near_disc(zoom, trans, c, s, _PANEL_ROWS)
        view[0], view[1], view[2], view[3], view[4] = c, s, zoom, trans[0], trans[1]
        view[5], view[6], view[7], view[8], view[9] = kx, ky, reach, self._sx, self._sy
        return view

    def _draw_track_compiled(self, kernels: Any, view: np.ndarray) -> bool:
        """``_draw_polygons`` with the culling and the vertices from one compiled call; False
        (having drawn nothing) if a vertex does not fit int32."""
        self._sync_polygons()
        xy = self._poly_xy
        if self._track_buf is None or self._track_buf[0] is not xy:
            out = np.empty((len(xy), 4, 2), np.int32)
            self._track_buf = (xy, out, np.empty(len(xy), np.int64), [[p] for p in out])
        _, out, index, polys = self._track_buf
        count = kernels.track_points(
            xy, self._poly_centre, self._poly_radius, view, float(_PANEL_ROWS), out, index
        )
        if count < 0:
            return False
        n_grass = len(_GRASS)
        road = self._road_colors
        drawn = index[:count].tolist()  # the grass squares first: they precede the road
        road_drawn = [road[i - n_grass] for i in drawn if i >= n_grass]
        # the colours as _visible_polygons makes them (stock int()s the road's, live arrays:
        # visited tiles are recoloured), in one conversion
        colors = [_bgr_free(self.grass_color)] * (count - len(road_drawn))
        if road_drawn:
            colors += np.array(road_drawn, dtype=np.float64).astype(np.int64).tolist()
        canvas = self._canvas
        fill = cv2.fillPoly
        for poly, color in zip(polys, colors, strict=False):  # polys[:count]
            fill(canvas, poly, color, cv2.LINE_8, _SHIFT)
        return True

    def _draw_car_compiled(self, kernels: Any, view: np.ndarray) -> bool:
        """``_draw_car_raster`` with the vertices from one compiled call (same polygons, same
        order: the hull's and wheels' fixtures, then the visible stripes); False (having drawn
        nothing) if a vertex does not fit int32."""
        self._sync_car()
        car = self.car
        buf = self._car_buf
        if buf is None or buf.car is not car:
            buf = self._car_buf = _CarBuffers(car, self._car_local, self._car_body, self._car_split)
        bodies = buf.bodies
        ang = np.asarray([obj.angle for obj in bodies], np.float64)  # np.cos as numpy's path
        pos, local = buf.pos, buf.local
        for b, obj in enumerate(bodies):
            p = obj.position
            pos[b, 0] = p.x
            pos[b, 1] = p.y
        stripes = []
        for row, obj, poly in buf.wheels:  # a wheel's stripe goes to its own rows
            if "phase" not in obj.__dict__:  # wheels have a phase, the hull has not
                continue
            stripe = _stripe_polygon(obj.phase)
            if stripe is None:
                continue
            for k in range(4):
                local[row + k, 0] = stripe[k][0]
                local[row + k, 1] = stripe[k][1]
            stripes.append(poly)
        if not kernels.car_points(
            local, buf.body, np.cos(ang), np.sin(ang), pos, view, len(local), buf.out
        ):
            return False
        canvas = self._canvas
        fill = cv2.fillPoly
        for poly, color in zip(buf.polys, self._car_colors, strict=True):
            fill(canvas, poly, color, cv2.LINE_8, _SHIFT)
        white = list(WHEEL_WHITE)
        for poly in stripes:  # after all the fixtures, in the bodies' order
            fill(canvas, poly, white, cv2.LINE_8, _SHIFT)
        return True

    def _sync_car(self) -> None:
        """The car's fixture vertices (body-local), bodies and colours, cached per ``Car``."""
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

    def _draw_car_raster(self, zoom: float, trans: tuple[float, float], c: float, s: float) -> None:
        """The hull and wheels (and the wheels' white stripes), as stock's ``Car.draw``.

        Every vertex is moved to the world with its body's position and angle in one numpy
        expression (stock lets Box2D transform them one by one).
        """
        self._sync_car()
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
        # one whose every vertex lies in the panel (flipped rows >= 700, canvas rows >= 84 *
        # supersample, hence frame rows >= 84 after the box averages) changes no kept pixel
        if not indicators or min([y for points, _ in indicators for _, y in points]) >= _PANEL_TOP:
            return
        indicators = [
            (points, color)
            for points, color in indicators
            if min(y for _, y in points) < _PANEL_TOP
        ]
        p = np.asarray([points for points, _ in indicators], np.float64)  # (K, 4, 2)
        # already flipped: _canvas_points maps (H - y) to canvas row y * sy
        pts = self._canvas_points(p[..., 0], WINDOW_H - p[..., 1])
        for poly, (_, color) in zip(pts, indicators, strict=True):
            cv2.fillPoly(self._canvas, [poly], color, cv2.LINE_8, _SHIFT)


def _bgr_free(color: Any) -> list[int]:
    """A colour as the int list cv2 wants (channels stay in RGB order: the canvas is RGB)."""
    return [int(v) for v in color]


def _black_rows(surf: pygame.Surface, top: int, bottom: int, width: int) -> None:
    """Paint rows ``top:bottom`` of ``surf`` black (nothing if empty), as ``pygame.draw.polygon``
    paints: a polygon fills the rows and columns of its integer vertices, ends included."""
    if bottom > top:
        pygame.draw.polygon(
            surf, (0, 0, 0), [(width - 1, bottom - 1), (width - 1, top), (0, top), (0, bottom - 1)]
        )


def _raster_kernels() -> Any:
    """:mod:`.raster_kernels` where it may be used, else None (resolved once per process)."""
    return load_kernels("raster_kernels")


class _CarBuffers:
    """The compiled car path's arrays for one ``Car``: the fixtures' body-local vertices followed
    by four rows per wheel for its stripe, their bodies, the bodies' positions, the canvas
    vertices, and one-polygon lists of views of them (fixtures; ``wheels``: each wheel's first
    stripe row, the wheel, its stripe's list) for ``cv2.fillPoly``."""

    def __init__(self, car: Any, local: np.ndarray, body: np.ndarray, split: np.ndarray) -> None:
        self.car = car
        self.bodies = list(car.drawlist)
        wheels = [b for b, obj in enumerate(self.bodies) if "phase" in obj.__dict__]
        n = len(local)
        size = n + 4 * len(wheels)
        self.local = np.zeros((size, 2), np.float64)
        self.local[:n] = local
        self.body = np.zeros(size, np.int64)
        self.body[:n] = body
        self.pos = np.zeros((len(self.bodies), 2), np.float64)
        self.out = np.zeros((size, 2), np.int32)
        self.polys = [[p] for p in np.split(self.out[:n], split)]
        self.wheels = []
        for k, b in enumerate(wheels):
            row = n + 4 * k
            self.body[row : row + 4] = b
            self.wheels.append((row, self.bodies[b], [self.out[row : row + 4]]))
