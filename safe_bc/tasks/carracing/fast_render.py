"""A faster CarRacing-v3 renderer whose frames are bit-identical to gymnasium's.

``FastCarRacing`` subclasses gymnasium's ``CarRacing`` and keeps its physics, rewards, track
generation and colours untouched; only the drawing is reorganised. Stock ``step()`` spends ~97%
of its time in ``_render("state_pixels")``. What changed, and why the pixels stay the same:

* **Culling is vectorised.** Stock rotates, scales and translates the ~770 polygons (400 grass
  squares, the road tiles and the curbs) one vertex at a time with ``pygame.math.Vector2`` and
  keeps a polygon when *any* vertex lies inside the window widened by ``MAX_SHAPE_DIM``. Here the
  vertices sit in one ``(N, 4, 2)`` float64 array per track (rebuilt when ``reset()`` makes a new
  ``road_poly`` list) and the same test runs in numpy. ``Vector2.rotate_rad`` reduces the angle
  with ``fmod`` to ``[0, 2pi)``, special-cases multiples of 90 degrees and otherwise computes
  ``(c*x - s*y, s*x + c*y)``; ``_rotation`` reproduces that, and numpy's float64 ``*``, ``-`` and
  ``+`` round exactly like the C and Python operations, so every survivor is drawn from the very
  same float coordinates (gfxdraw then truncates them to ``Sint16`` as before). Colours are read
  at draw time: tile colours are arrays that the contact listener recolours in place. Only the
  polygons whose world centre lies within reach of the visible area (one disc test in world
  coordinates, a superset of what the exact test keeps) go through that test.
* **Polygons that cannot touch a visible pixel are skipped.** Stock's margin is ~382 px, so about
  two thirds of the ~67 polygons it draws lie wholly outside the window (or under the indicator
  bar). A filled polygon stays inside the bounding box of its integer vertices and its
  anti-aliased outline within a pixel of it, so one whose bounding box is more than 3 px outside
  the kept area changes nothing there. The others are drawn in stock's order with stock's calls.
* **The track is drawn by compiled code.** Stock draws each polygon with
  ``gfxdraw.aapolygon`` and ``gfxdraw.filled_polygon``; ``gfx_kernels`` ports those two SDL_gfx
  functions to numba, integer for integer (line clipping with float32 slopes, Wu's error
  accumulator, the blend, the 16.16 scanline fill), and draws all polygons of a frame in one
  call on the surface's pixels, skipping the rows the indicator panel covers. The ports are
  checked against pygame on random polygons once per process; if numba is missing or the
  check fails, pygame's calls are used; ``SAFE_BC_COMPILED_DRAWING=0`` chooses them too
  (numba and LLVM cost memory in every process: ``make bench``'s memory columns).
* **The background** is stock's ``PLAYFIELD`` square drawn with ``gfxdraw``. Once it covers the
  window with a margin (after the zoom-in) it sets every pixel to its colour and its outline is
  off-screen, so ``Surface.fill`` with the pixel value gfxdraw maps the colour to (read back from
  a 4x4 scratch surface, so domain-randomised float colours map identically) is equivalent.
  When the car is far from every edge of the playfield that holds without computing the square's
  vertices. During the zoom-in the stock polygon is drawn.
* **The font** is loaded once (stock loads ``pygame.font.Font`` from disk every step), and
  reloaded after a ``pygame.quit()`` (counted with a quit hook); the score text is re-rendered
  only when the score string changes.
* **No 1000x800 flip.** ``smoothscale`` shrinks X first (row by row) into a temporary buffer and
  then Y, so ``smoothscale(S, (96, 96))`` equals ``smoothscale(smoothscale(S, (96, 800)),
  (96, 96))``, and the X pass commutes with a vertical flip. The road and car are drawn unflipped,
  X-shrunk to 96x700, and only that small result is flipped. The indicator panel covers the
  bottom 100 rows of the flipped frame completely (black polygon), so it is drawn on a surface of
  its own, X-shrunk separately and placed below; the road rows it hides are neither filled nor
  shrunk. If an indicator bar would reach above the panel (extreme speed or wheel spin), that
  frame is composed the stock way (flip, draw indicators, smoothscale).
* **The car** is drawn with stock's ``pygame.draw.polygon`` calls and coordinates: Box2D still
  transforms the (cached) fixture vertices, then the same float operations replace the
  per-vertex ``Vector2`` objects.
* Surfaces are reused between frames (rebuilt if a display appears, since new surfaces take the
  display's pixel format), and the frame is read with ``pygame.image.tobytes``.

``render_mode="rgb_array"``/``"human"`` frames use the fast road drawing with stock's car (and
skid-mark particles), flip, indicators and scaling. After a ``state_pixels`` render
``self.surf`` holds the unflipped road-and-car surface rather than the final composed frame.
Editing ``road_poly`` vertices in place after ``reset()`` is not noticed (appending is).

``tests/tasks/carracing/test_fast_render.py`` checks frames against stock gymnasium;
``python -m benchmarks.bench --cases env`` measures the speed-up.
"""

from __future__ import annotations

import math
import os
import warnings
from typing import Any

import numpy as np
import pygame
from gymnasium.envs.box2d.car_dynamics import SIZE, WHEEL_R, WHEEL_W, WHEEL_WHITE
from gymnasium.envs.box2d.car_racing import (
    GRASS_DIM,
    MAX_SHAPE_DIM,
    PLAYFIELD,
    SCALE,
    STATE_H,
    STATE_W,
    VIDEO_H,
    VIDEO_W,
    WINDOW_H,
    WINDOW_W,
    ZOOM,
    CarRacing,
)
from pygame import gfxdraw

from safe_bc.tasks.carracing.compiled import COMPILED_ENV

__all__ = ["FastCarRacing"]

_TWO_PI = 2.0 * math.pi
_SQRT2 = math.sqrt(2.0) * (1.0 + 1e-9)
_HALF_PI = math.pi / 2.0
_VECTOR_EPSILON = 1e-6  # pygame's default Vector2 epsilon, used by rotate_rad
_EXACT_QUARTER_TURNS = {0: (1.0, 0.0), 1: (0.0, 1.0), 2: (-1.0, 0.0), 3: (0.0, -1.0), 4: (1.0, 0.0)}

_PANEL_ROWS = WINDOW_H // 8  # the indicator panel: H - 5 * (H / 40) .. H, i.e. 100 rows
_PANEL_TOP = WINDOW_H - _PANEL_ROWS
_SKIP_MARGIN = 3.0  # px; a polygon further than this outside the kept area draws nothing there
_BG_MARGIN = 4.0  # px the background square must extend beyond the window to be a plain fill
_SINT16_SAFE = 30000.0  # gfxdraw casts coordinates to Sint16
_XRGB_MASKS = (0xFF0000, 0xFF00, 0xFF)  # pygame's default 32-bit format, the one gfx_kernels draws
# px from the car's screen point (W / 2, H / 4) to the farthest corner of the window widened by
# _BG_MARGIN, plus _BG_MARGIN and 8 px of slack for the truncated vertices
_FIELD_COVER_PX = math.hypot(WINDOW_W / 2 + _BG_MARGIN, 3 * WINDOW_H / 4 + _BG_MARGIN) + 12.0


class _PygameSession:
    """Counts ``pygame.quit()`` calls (which unload fonts) via a quit hook."""

    generation = 0
    hooked = False


def _on_pygame_quit() -> None:
    _PygameSession.generation += 1
    _PygameSession.hooked = False  # pygame forgets its quit hooks after calling them


def _pygame_generation() -> int:
    """Number of ``pygame.quit()`` calls so far (hooking the next one if needed)."""
    if not _PygameSession.hooked:
        pygame.register_quit(_on_pygame_quit)
        _PygameSession.hooked = True
    return _PygameSession.generation


class _Compiled:
    """The compiled track drawing, resolved once per process (see :func:`_compiled_draw`)."""

    draw: Any = None
    resolved = False


COMPILED_DRAWING_ENV = COMPILED_ENV
"""Set to ``0`` to draw with pygame's own calls and never import numba: the same frames, slower
steps and less memory per process that renders CarRacing (numba and LLVM); ``make bench``'s
env case measures both ways (:mod:`.compiled`: the switch of every compiled kernel)."""


def _compiled_draw() -> Any:
    """``gfx_kernels.draw_polygons`` if numba is installed, :data:`COMPILED_DRAWING_ENV` is not
    ``0``, and the ports draw exactly what pygame's ``gfxdraw`` draws here (checked once per
    process on random polygons), else None: the renderer then calls pygame itself and frames
    stay identical either way."""
    if not _Compiled.resolved:
        _Compiled.resolved = True
        if os.environ.get(COMPILED_DRAWING_ENV, "1").strip() == "0":
            return None
        try:
            from safe_bc.tasks.carracing import gfx_kernels
        except ImportError:  # numba is not installed
            return None
        if gfx_kernels.matches_pygame():
            _Compiled.draw = gfx_kernels.draw_polygons
        else:
            warnings.warn(
                "safe_bc: the compiled gfxdraw ports disagree with this pygame-ce; CarRacing "
                "frames are drawn with pygame's own (slower) calls",
                RuntimeWarning,
                stacklevel=2,
            )
    return _Compiled.draw


def _gfxdraw_pixel(color: Any, like: pygame.Surface) -> int:
    """The pixel value gfxdraw writes for ``color`` on a surface of ``like``'s format: drawn on
    a 4x4 scratch surface and read back, so float (domain-randomised) colours map as gfxdraw
    maps them."""
    scratch = pygame.Surface((4, 4), 0, like)
    gfxdraw.filled_polygon(scratch, [(-8, -8), (8, -8), (8, 8), (-8, 8)], color)
    return scratch.get_at_mapped((1, 1))


def _grass_polygons() -> np.ndarray:
    """Stock's grass squares, built with the same float expressions; shape ``(400, 4, 2)``."""
    grass = []
    for x in range(-20, 20, 2):
        for y in range(-20, 20, 2):
            grass.append(
                [
                    (GRASS_DIM * x + GRASS_DIM, GRASS_DIM * y + 0),
                    (GRASS_DIM * x + 0, GRASS_DIM * y + 0),
                    (GRASS_DIM * x + 0, GRASS_DIM * y + GRASS_DIM),
                    (GRASS_DIM * x + GRASS_DIM, GRASS_DIM * y + GRASS_DIM),
                ]
            )
    return np.asarray(grass, dtype=np.float64)


_GRASS = _grass_polygons()
_FIELD = (
    (PLAYFIELD, PLAYFIELD),
    (PLAYFIELD, -PLAYFIELD),
    (-PLAYFIELD, -PLAYFIELD),
    (-PLAYFIELD, PLAYFIELD),
)


def _rotation(angle: float) -> tuple[float, float]:
    """``(cos, sin)`` exactly as ``pygame.math.Vector2.rotate_rad`` uses them.

    pygame reduces the angle with ``fmod`` to ``[0, 2pi)`` and replaces rotations within 1e-6 of
    a multiple of 90 degrees by exact coordinate swaps; multiplying by the exact 0/1/-1 returned
    here gives the same results.
    """
    a = math.fmod(angle, _TWO_PI)
    if a < 0:
        a += _TWO_PI
    if math.fmod(a + _VECTOR_EPSILON, _HALF_PI) < 2 * _VECTOR_EPSILON:
        return _EXACT_QUARTER_TURNS[int((a + _VECTOR_EPSILON) / _HALF_PI)]
    return math.cos(a), math.sin(a)


def _to_screen(
    xy: np.ndarray, zoom: float, translation: tuple[float, float], angle: float
) -> tuple[np.ndarray, np.ndarray]:
    """Screen coordinates of world points ``xy`` (shape ``(..., 2)``), as stock computes them.

    Returns ``(px, py)``, each of shape ``xy.shape[:-1]``, float64, bit-equal to stock's
    ``Vector2(p).rotate_rad(angle)`` followed by ``c * zoom + translation``.
    """
    c, s = _rotation(angle)
    x = xy[..., 0]
    y = xy[..., 1]
    px = (c * x - s * y) * zoom + translation[0]
    py = (s * x + c * y) * zoom + translation[1]
    return px, py


class FastCarRacing(CarRacing):
    """gymnasium ``CarRacing`` with a faster, pixel-identical ``_render``.

    Same constructor, spaces, dynamics and rewards as ``CarRacing``; observations are
    ``(96, 96, 3)`` uint8 frames equal to stock's for the same seed and actions.
    """

    compiled_drawing = True
    """Draw the track with the compiled ports of ``gfx_kernels`` where they are available (the
    frames are the same either way; ``False`` calls pygame's gfxdraw, for benchmarks)."""

    def __init__(
        self,
        render_mode: str | None = None,
        verbose: bool = False,
        lap_complete_percent: float = 0.95,
        domain_randomize: bool = False,
        continuous: bool = True,
    ) -> None:
        super().__init__(
            render_mode=render_mode,
            verbose=verbose,
            lap_complete_percent=lap_complete_percent,
            domain_randomize=domain_randomize,
            continuous=continuous,
        )
        self._font: pygame.font.Font | None = None
        self._font_generation = -1  # _pygame_generation() when self._font was loaded
        self._text_cache: tuple[str, pygame.Surface] | None = None
        self._road_src: list | None = None  # the road_poly list the arrays below were built from
        self._road_len = 0
        self._poly_xy: np.ndarray = _GRASS  # (N, 4, 2) grass squares then road_poly, stock order
        self._poly_centre = _GRASS.mean(axis=1)  # (N, 2) world centres of the polygons
        self._poly_radius = np.zeros(len(_GRASS))  # (N,) world distance centre -> farthest vertex
        self._road_colors: list[Any] = []  # road_poly colours (tile colours are live arrays)
        self._fill_cache: tuple[tuple[float, ...], int] | None = None
        self._rgb_cache: dict[tuple[float, ...], int] = {}  # colour -> 0x00RRGGBB, gfxdraw's
        self._bufs: _Buffers | None = None
        self._car_src: Any = None  # the Car whose fixture vertices are cached below
        self._car_shapes: list[tuple[Any, list[list[tuple[float, float]]]]] = []

    # ------------------------------------------------------------------ caches
    def _sync_polygons(self) -> None:
        """Rebuild the polygon array when ``reset()`` has made a new track."""
        road_poly = self.road_poly
        if road_poly is self._road_src and len(road_poly) == self._road_len:
            return
        if road_poly:
            road = np.asarray([poly for poly, _ in road_poly], dtype=np.float64)
            self._poly_xy = np.concatenate([_GRASS, road.reshape(-1, 4, 2)])
        else:
            self._poly_xy = _GRASS
        self._poly_centre = self._poly_xy.mean(axis=1)
        self._poly_radius = np.sqrt(
            ((self._poly_xy - self._poly_centre[:, None, :]) ** 2).sum(axis=2)
        ).max(axis=1) * (1.0 + 1e-9)
        self._road_colors = [color for _, color in road_poly]
        self._road_src = road_poly
        self._road_len = len(road_poly)

    def _ensure_font(self) -> None:
        """Stock calls ``pygame.font.init()`` every frame; a font loaded before a
        ``pygame.quit()`` (say, by closing a human-mode env) must not be used afterwards."""
        if not pygame.font.get_init():
            pygame.font.init()
        generation = _pygame_generation()
        if generation != self._font_generation:
            self._font = None
            self._text_cache = None
            self._font_generation = generation

    def _get_font(self) -> pygame.font.Font:
        """The score font, loaded once (stock loads it from disk every frame)."""
        if self._font is None:
            self._font = pygame.font.Font(pygame.font.get_default_font(), 42)
        return self._font

    def _score_text(self) -> pygame.Surface:
        """Rendered score digits, reused while the string is unchanged."""
        label = f"{self.reward:04.0f}"
        if self._text_cache is None or self._text_cache[0] != label:
            try:
                text = self._get_font().render(label, True, (255, 255, 255), (0, 0, 0))
            except pygame.error:  # font module quit and re-initialised behind our back
                self._font = None
                text = self._get_font().render(label, True, (255, 255, 255), (0, 0, 0))
            self._text_cache = (label, text)
        return self._text_cache[1]

    def _bg_pixel(self) -> int:
        """The mapped pixel value gfxdraw writes for ``self.bg_color`` on ``self.surf``."""
        key = tuple(float(c) for c in self.bg_color)
        if self._fill_cache is None or self._fill_cache[0] != key:
            assert self.surf is not None
            self._fill_cache = (key, _gfxdraw_pixel(self.bg_color, self.surf))
        return self._fill_cache[1]

    # ------------------------------------------------------------------ drawing
    def _render_road(
        self,
        zoom: float,
        translation: tuple[float, float],
        angle: float,
        visible_top: int = 0,
    ) -> None:
        """Draw background, grass and road on ``self.surf`` exactly as stock does.

        ``visible_top``: rows above it are known to be painted over later (the indicator panel,
        in unflipped coordinates), so polygons entirely above it may be skipped.
        """
        surf = self.surf
        assert surf is not None
        self._draw_background(zoom, translation, angle, visible_top)

        px, py, colors = self._visible_polygons(zoom, translation, angle, visible_top)
        if self._draw_compiled(surf, px, py, colors, visible_top):
            return
        pts = np.stack([px, py], axis=-1).tolist()  # (D, 4, 2) Python floats
        aapolygon = gfxdraw.aapolygon
        filled_polygon = gfxdraw.filled_polygon
        for poly, color in zip(pts, colors, strict=True):
            aapolygon(surf, poly, color)
            filled_polygon(surf, poly, color)

    def _draw_compiled(
        self,
        surf: pygame.Surface,
        px: np.ndarray,
        py: np.ndarray,
        colors: list[Any],
        visible_top: int,
    ) -> bool:
        """Stock's ``aapolygon`` + ``filled_polygon`` pairs through the compiled ports in
        ``gfx_kernels``; False (having drawn nothing) where they cannot be used: numba missing,
        the once-per-process check against pygame failed, or a surface, colour or coordinate
        that the ports do not cover."""
        draw = _compiled_draw() if self.compiled_drawing else None
        if draw is None or surf.get_bitsize() != 32 or surf.get_masks()[:3] != _XRGB_MASKS:
            return False
        if px.size and max(np.abs(px).max(), np.abs(py).max()) > _SINT16_SAFE:
            return False
        packed = np.empty(len(colors), np.int64)
        for i, color in enumerate(colors):
            rgb = self._gfx_rgb(color, surf)
            if rgb is None:
                return False
            packed[i] = rgb
        # gfxdraw converts each coordinate with int() (towards zero), then to Sint16
        vx = np.trunc(px).astype(np.int64)
        vy = np.trunc(py).astype(np.int64)
        pixels = pygame.surfarray.pixels2d(surf).T  # (H, W) view; locks surf until deleted
        try:
            draw(pixels, vx, vy, packed, visible_top)
        finally:
            del pixels
        return True

    def _gfx_rgb(self, color: Any, surf: pygame.Surface) -> int | None:
        """``0x00RRGGBB`` of a colour as gfxdraw reads it (``surf``: an XRGB surface), or None
        if it is not three ints in ``0..255`` (the grass colour, a float array under domain
        randomisation, is mapped by drawing it once, :func:`_gfxdraw_pixel`, as ``_bg_pixel``
        does)."""
        if isinstance(color, list) and len(color) == 3:
            r, g, b = color
            if 0 <= r < 256 and 0 <= g < 256 and 0 <= b < 256:
                return (r << 16) | (g << 8) | b
            return None
        key = tuple(float(c) for c in color)
        cached = self._rgb_cache.get(key)
        if cached is None:  # surf has _XRGB_MASKS: its pixel value is 0x00RRGGBB
            cached = self._rgb_cache[key] = _gfxdraw_pixel(color, surf)
        return cached

    def _visible_polygons(
        self, zoom: float, translation: tuple[float, float], angle: float, visible_top: int
    ) -> tuple[np.ndarray, np.ndarray, list[Any]]:
        """The grass and road polygons stock would draw that can reach a kept pixel, in stock's
        order: their screen coordinates ``px, py`` (``(D, 4)`` float64 each, stock's floats)
        and colours (the grass colour as stock passes it, road colours int()ed as stock does).
        """
        self._sync_polygons()
        near = self._near_polygons(zoom, translation, angle, visible_top)
        px, py = _to_screen(self._poly_xy[near], zoom, translation, angle)  # (K, 4) each
        # stock's test: keep a polygon if any vertex is inside the window +- MAX_SHAPE_DIM ...
        inside = (
            (px >= -MAX_SHAPE_DIM)
            & (px <= WINDOW_W + MAX_SHAPE_DIM)
            & (py >= -MAX_SHAPE_DIM)
            & (py <= WINDOW_H + MAX_SHAPE_DIM)
        ).any(axis=1)
        # ... and of those only the ones whose bounding box reaches a kept pixel
        touches = (
            inside
            & (px.max(axis=1) >= -_SKIP_MARGIN)
            & (px.min(axis=1) <= WINDOW_W + _SKIP_MARGIN)
            & (py.max(axis=1) >= visible_top - _SKIP_MARGIN)
            & (py.min(axis=1) <= WINDOW_H + _SKIP_MARGIN)
        )
        drawn = near[touches]
        n_grass = len(_GRASS)
        road_drawn = (drawn[drawn >= n_grass] - n_grass).tolist()
        # stock int()s each road colour channel (tile colours are float arrays, changed in place
        # when a tile is visited, so they are read every frame); astype truncates the same way
        colors: list[Any] = [self.grass_color] * (drawn.size - len(road_drawn))
        if road_drawn:
            rgb = np.array([self._road_colors[i] for i in road_drawn], dtype=np.float64)
            colors += rgb.astype(np.int64).tolist()
        return px[touches], py[touches], colors

    def _near_polygons(
        self, zoom: float, translation: tuple[float, float], angle: float, visible_top: int
    ) -> np.ndarray:
        """Sorted indices of the polygons that may reach the kept area (a superset of those
        stock would draw there), from a disc test in world coordinates.

        The exact test of ``_render_road`` keeps a polygon whose screen bounding box reaches the
        kept area ``[0, W] x [visible_top, H]`` widened by the skip margin. That bounding box
        lies within ``sqrt(2) * radius * zoom`` px of the polygon's centre, and the widened
        area within ``reach`` px of its own centre; the screen transform is a rotation, a zoom
        and a translation, so a polygon whose world centre is further than
        ``sqrt(2) * radius + reach / zoom`` from the world point under that centre cannot pass.
        """
        kx, ky, reach = _near_disc(zoom, translation, *_rotation(angle), visible_top)
        limit = self._poly_radius * _SQRT2 + reach
        dx = self._poly_centre[:, 0] - kx
        dy = self._poly_centre[:, 1] - ky
        return np.flatnonzero(dx * dx + dy * dy <= limit * limit)

    def _draw_background(
        self, zoom: float, translation: tuple[float, float], angle: float, visible_top: int = 0
    ) -> None:
        """Stock's background square: a plain fill when it covers the window, else gfxdraw.

        Rows above ``visible_top`` are hidden later and need no fill (drawing on other rows
        never reads them).
        """
        surf = self.surf
        assert surf is not None
        if self._field_covers_window(zoom):
            surf.fill(self._bg_pixel(), (0, visible_top, WINDOW_W, WINDOW_H - visible_top))
            return
        c, s = _rotation(angle)
        tx, ty = translation
        poly = [((c * x - s * y) * zoom + tx, (s * x + c * y) * zoom + ty) for x, y in _FIELD]
        if self._covers_window([p[0] for p in poly], [p[1] for p in poly]):
            surf.fill(self._bg_pixel(), (0, visible_top, WINDOW_W, WINDOW_H - visible_top))
            return
        surf.fill(0)  # stock draws on a fresh (zeroed) Surface
        gfxdraw.aapolygon(surf, poly, self.bg_color)
        gfxdraw.filled_polygon(surf, poly, self.bg_color)

    def _field_covers_window(self, zoom: float) -> bool:
        """A cheap sufficient condition for ``_covers_window`` of the playfield square.

        The car is drawn at screen ``(W / 2, H / 4)`` whatever the rotation, and every point of
        the window widened by ``_BG_MARGIN`` lies within ``_FIELD_COVER_PX`` px of it. If the
        car is further than that (in px, plus slack for gfxdraw's integer truncation of the
        vertices) from every edge of the axis-aligned playfield, the rotated square contains
        that disc, hence the widened window, at least ``_BG_MARGIN`` inside each of its edges;
        its vertices then also stay far below gfxdraw's ``Sint16`` limit.
        """
        car = self.car
        assert car is not None
        x, y = car.hull.position
        inner = PLAYFIELD - max(abs(x), abs(y))
        return zoom <= ZOOM * SCALE and inner * zoom > _FIELD_COVER_PX

    @staticmethod
    def _covers_window(px: list[float], py: list[float]) -> bool:
        """True if the convex quad ``(px, py)`` (4 screen points) contains the widened window.

        Uses the integer vertices gfxdraw draws with and requires each window corner, widened by
        ``_BG_MARGIN``, to lie at least ``_BG_MARGIN`` inside every edge.
        """
        if max(map(abs, px)) > _SINT16_SAFE or max(map(abs, py)) > _SINT16_SAFE:
            return False
        qx = [float(int(v)) for v in px]  # gfxdraw truncates towards zero
        qy = [float(int(v)) for v in py]
        m = _BG_MARGIN
        corners = ((-m, -m), (WINDOW_W + m, -m), (WINDOW_W + m, WINDOW_H + m), (-m, WINDOW_H + m))
        signs = set()
        for i in range(4):
            x0, y0 = qx[i], qy[i]
            ex, ey = qx[(i + 1) % 4] - x0, qy[(i + 1) % 4] - y0
            length = math.hypot(ex, ey)
            if length == 0.0:
                return False
            for cx, cy in corners:
                dist = (ex * (cy - y0) - ey * (cx - x0)) / length
                if abs(dist) < m:
                    return False
                signs.add(dist > 0)
        return len(signs) == 1

    def _draw_car(
        self, surf: pygame.Surface, zoom: float, translation: tuple[float, float], angle: float
    ) -> None:
        """Stock ``Car.draw(..., draw_particles=False)`` without per-vertex ``Vector2`` objects.

        Box2D still transforms the vertices (``transform * v``); the rotation, zoom and
        translation are the same float operations as stock's.
        """
        car = self.car
        assert car is not None
        c, s = _rotation(angle)
        tx, ty = translation
        draw_polygon = pygame.draw.polygon
        if self._car_src is not car:  # a new Car per reset; its bodies' shapes never change
            self._car_shapes = [
                (obj, [list(f.shape.vertices) for f in obj.fixtures]) for obj in car.drawlist
            ]
            self._car_src = car
        for obj, shapes in self._car_shapes:
            trans = obj.transform  # every fixture of obj belongs to body obj
            color = [int(v * 255) for v in obj.color]
            has_phase = "phase" in obj.__dict__  # wheels have a phase, the hull has not
            for vertices in shapes:
                path = [trans * v for v in vertices]
                draw_polygon(
                    surf,
                    color=color,
                    points=[
                        ((c * p[0] - s * p[1]) * zoom + tx, (s * p[0] + c * p[1]) * zoom + ty)
                        for p in path
                    ],
                )
                if not has_phase:
                    continue
                white_poly = _stripe_polygon(obj.phase)
                if white_poly is None:
                    continue
                path = [trans * v for v in white_poly]
                draw_polygon(
                    surf,
                    color=WHEEL_WHITE,
                    points=[
                        ((c * p[0] - s * p[1]) * zoom + tx, (s * p[0] + c * p[1]) * zoom + ty)
                        for p in path
                    ],
                )

    def _indicator_polygons(self, W: float, H: float) -> list[tuple[list, tuple[int, int, int]]]:
        """Stock's indicator polygons (after the black panel), same floats, same order."""
        s = W / 40.0
        h = H / 40.0

        def vertical_ind(place: float, val: float) -> list:
            return [
                (place * s, H - (h + h * val)),
                ((place + 1) * s, H - (h + h * val)),
                ((place + 1) * s, H - h),
                ((place + 0) * s, H - h),
            ]

        def horiz_ind(place: float, val: float) -> list:
            return [
                ((place + 0) * s, H - 4 * h),
                ((place + val) * s, H - 4 * h),
                ((place + val) * s, H - 2 * h),
                ((place + 0) * s, H - 2 * h),
            ]

        car = self.car
        assert car is not None
        vx, vy = car.hull.linearVelocity
        # stock's np.sqrt(np.square(vx) + np.square(vy)): the same IEEE operations on floats
        true_speed = math.sqrt(vx * vx + vy * vy)
        w = car.wheels
        candidates = [
            (true_speed, vertical_ind(5, 0.02 * true_speed), (255, 255, 255)),
            (w[0].omega, vertical_ind(7, 0.01 * w[0].omega), (0, 0, 255)),
            (w[1].omega, vertical_ind(8, 0.01 * w[1].omega), (0, 0, 255)),
            (w[2].omega, vertical_ind(9, 0.01 * w[2].omega), (51, 0, 255)),
            (w[3].omega, vertical_ind(10, 0.01 * w[3].omega), (51, 0, 255)),
            (w[0].joint.angle, horiz_ind(20, -10.0 * w[0].joint.angle), (0, 255, 0)),
            (
                car.hull.angularVelocity,
                horiz_ind(30, -0.8 * car.hull.angularVelocity),
                (255, 0, 0),
            ),
        ]
        return [(points, color) for value, points, color in candidates if abs(value) > 1e-4]

    def _render_indicators(self, W: float, H: float) -> None:
        """Stock's indicator bar on ``self.surf``."""
        self._draw_panel(self.surf, self._indicator_polygons(W, H))

    def _draw_panel(
        self, panel: pygame.Surface, indicators: list[tuple[list, tuple[int, int, int]]]
    ) -> None:
        """Stock's indicator panel without the score (rows 700..799 of the flipped frame,
        entirely repainted: the black polygon, then ``indicators``) on ``panel``."""
        W, H = WINDOW_W, WINDOW_H
        h = H / 40.0
        pygame.draw.polygon(
            panel, color=(0, 0, 0), points=[(W, H), (W, H - 5 * h), (0, H - 5 * h), (0, H)]
        )
        for points, color in indicators:
            pygame.draw.polygon(panel, points=points, color=color)

    def _draw_score(self, surf: pygame.Surface) -> bool:
        """Blit the score like stock; return False (drawing nothing) if it would leave the panel."""
        text, text_rect = self._score_placement()
        surf.blit(text, text_rect)
        return text_rect.top >= _PANEL_TOP

    def _score_placement(self) -> tuple[pygame.Surface, pygame.Rect]:
        """The score text and where stock blits it."""
        text = self._score_text()
        text_rect = text.get_rect()
        text_rect.center = (60, WINDOW_H - WINDOW_H * 2.5 / 40.0)
        return text, text_rect

    # ------------------------------------------------------------------ frame
    def _view(self) -> tuple[float, tuple[float, float], float]:
        """The camera: ``(zoom, translation, angle)``, computed verbatim as stock does."""
        assert self.car is not None
        angle = -self.car.hull.angle
        zoom = 0.1 * SCALE * max(1 - self.t, 0) + ZOOM * SCALE * min(self.t, 1)
        scroll_x = -(self.car.hull.position[0]) * zoom
        scroll_y = -(self.car.hull.position[1]) * zoom
        trans = pygame.math.Vector2((scroll_x, scroll_y)).rotate_rad(angle)
        return zoom, (WINDOW_W / 2 + trans[0], WINDOW_H / 4 + trans[1]), angle

    def _render(self, mode: str) -> Any:
        assert mode in self.metadata["render_modes"]

        self._ensure_font()
        if self.screen is None and mode == "human":
            pygame.display.init()
            self.screen = pygame.display.set_mode((WINDOW_W, WINDOW_H))
        if self.clock is None:
            self.clock = pygame.time.Clock()

        if "t" not in self.__dict__:
            return None  # reset() not called yet

        zoom, trans, angle = self._view()

        if mode == "state_pixels":
            indicators = self._indicator_polygons(WINDOW_W, WINDOW_H)
            if all(min(p[1] for p in points) >= _PANEL_TOP + 1 for points, _ in indicators):
                frame = self._state_pixels_fast(zoom, trans, angle, indicators)
                if frame is not None:
                    return frame

        # stock composition: draw, flip the 1000x800 surface, indicators, score, scale
        self.surf = self._fresh_road_surface()
        self._render_road(zoom, trans, angle)
        if mode == "state_pixels":
            self._draw_car(self.surf, zoom, trans, angle)
        else:  # with skid-mark particles
            self.car.draw(self.surf, zoom, trans, angle, True)
        self.surf = pygame.transform.flip(self.surf, False, True)
        self._render_indicators(WINDOW_W, WINDOW_H)
        self._draw_score(self.surf)

        if mode == "human":
            pygame.event.pump()
            self.clock.tick(self.metadata["render_fps"])
            assert self.screen is not None
            self.screen.fill(0)
            self.screen.blit(self.surf, (0, 0))
            pygame.display.flip()
            return None
        if mode == "rgb_array":
            return self._create_image_array(self.surf, (VIDEO_W, VIDEO_H))
        if mode == "state_pixels":
            return self._create_image_array(self.surf, (STATE_W, STATE_H))
        return self.isopen

    def _buffers(self) -> _Buffers:
        """Reused surfaces, rebuilt when the display (hence the default pixel format) changes."""
        display = pygame.display.get_surface() if pygame.display.get_init() else None
        if self._bufs is None or self._bufs.display is not display:
            self._bufs = _Buffers(display)
            self._fill_cache = None
        return self._bufs

    def _fresh_road_surface(self) -> pygame.Surface:
        """The reused 1000x800 surface the road is drawn on (stock makes a new one per frame)."""
        return self._buffers().road

    def _create_image_array(self, screen: pygame.Surface, size: tuple[int, int]) -> np.ndarray:
        """Stock's smoothscale to ``size``; returns ``(size[1], size[0], 3)`` uint8, C-contiguous.

        Same values (and layout) as stock's transpose of a ``pixels3d`` copy, read faster.
        """
        return _surface_rgb(pygame.transform.smoothscale(screen, size))

    def _state_pixels_fast(
        self,
        zoom: float,
        trans: tuple[float, float],
        angle: float,
        indicators: list[tuple[list, tuple[int, int, int]]],
    ) -> np.ndarray | None:
        """The 96x96 state without flipping the 1000x800 surface; ``(96, 96, 3)`` uint8.

        Returns None (having drawn nothing visible) if the score text would leave the panel.
        """
        bufs = self._buffers()
        self._draw_panel(bufs.panel, indicators)
        if not self._draw_score(bufs.panel):
            return None

        # road and car, unflipped: flipped rows < 700 are unflipped rows >= 100
        self.surf = bufs.road
        self._render_road(zoom, trans, angle, visible_top=_PANEL_ROWS)
        self._draw_car(self.surf, zoom, trans, angle)

        # smoothscale = X pass (row by row, so it commutes with a vertical flip), then Y pass
        smoothscale = pygame.transform.smoothscale
        smoothscale(bufs.road_rows, (STATE_W, _PANEL_TOP), bufs.road_x)
        bufs.frame_x.blit(pygame.transform.flip(bufs.road_x, False, True), (0, 0))
        smoothscale(bufs.panel_rows, (STATE_W, _PANEL_ROWS), bufs.panel_x)
        smoothscale(bufs.frame_x, (STATE_W, STATE_H), bufs.state)
        return _surface_rgb(bufs.state)


def _near_disc(
    zoom: float, translation: tuple[float, float], c: float, s: float, visible_top: int
) -> tuple[float, float, float]:
    """``FastCarRacing._near_polygons``' disc: the world point ``(kx, ky)`` under the centre of
    the kept area and the world distance ``(reach + 2) / zoom`` that, added to a polygon's
    ``sqrt(2) * radius``, bounds how far from it the polygon's centre may lie."""
    tx, ty = translation
    margin = _SKIP_MARGIN + 2.0
    sx = WINDOW_W / 2.0 - tx
    sy = (visible_top + WINDOW_H) / 2.0 - ty
    # inverse rotation of the screen offset, then un-zoom: world point under the centre
    kx = (c * sx + s * sy) / zoom
    ky = (-s * sx + c * sy) / zoom
    reach = math.hypot(WINDOW_W / 2.0 + margin, (WINDOW_H - visible_top) / 2.0 + margin)
    return kx, ky, (reach + 2.0) / zoom


def _stripe_polygon(phase: float) -> list[tuple[float, float]] | None:
    """The white stripe stock's ``Car.draw`` paints on a wheel at ``phase`` (wheel-local
    vertices, stock's floats), or None where it is hidden."""
    a1 = phase
    a2 = phase + 1.2  # radians
    s1 = math.sin(a1)
    s2 = math.sin(a2)
    c1 = math.cos(a1)
    c2 = math.cos(a2)
    if s1 > 0 and s2 > 0:
        return None
    if s1 > 0:
        c1 = np.sign(c1)
    if s2 > 0:
        c2 = np.sign(c2)
    return [
        (-WHEEL_W * SIZE, +WHEEL_R * c1 * SIZE),
        (+WHEEL_W * SIZE, +WHEEL_R * c1 * SIZE),
        (+WHEEL_W * SIZE, +WHEEL_R * c2 * SIZE),
        (-WHEEL_W * SIZE, +WHEEL_R * c2 * SIZE),
    ]


def _surface_rgb(surf: pygame.Surface) -> np.ndarray:
    """``(h, w, 3)`` uint8 copy of a surface's RGB values."""
    w, h = surf.get_size()
    return np.frombuffer(pygame.image.tobytes(surf, "RGB"), dtype=np.uint8).reshape(h, w, 3).copy()


class _Buffers:
    """Surfaces reused across frames, all in the pixel format a new ``pygame.Surface`` gets."""

    def __init__(self, display: pygame.Surface | None) -> None:
        self.display = display
        self.road = pygame.Surface((WINDOW_W, WINDOW_H))  # road and car, unflipped
        self.road_rows = self.road.subsurface((0, _PANEL_ROWS, WINDOW_W, _PANEL_TOP))
        self.panel = pygame.Surface((WINDOW_W, WINDOW_H), 0, self.road)  # indicators, flipped
        self.panel_rows = self.panel.subsurface((0, _PANEL_TOP, WINDOW_W, _PANEL_ROWS))
        self.road_x = pygame.Surface((STATE_W, _PANEL_TOP), 0, self.road)  # X-shrunk road
        self.frame_x = pygame.Surface((STATE_W, WINDOW_H), 0, self.road)  # X-shrunk frame
        self.panel_x = self.frame_x.subsurface((0, _PANEL_TOP, STATE_W, _PANEL_ROWS))
        self.state = pygame.Surface((STATE_W, STATE_H), 0, self.road)
