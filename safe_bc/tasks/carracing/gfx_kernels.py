"""Compiled ports of the two pygame-ce ``gfxdraw`` calls that CarRacing draws its track with.

Stock CarRacing draws every grass square and road tile with ``gfxdraw.aapolygon`` followed by
``gfxdraw.filled_polygon``; both are SDL_gfx C functions that pygame-ce bundles
(``src_c/SDL_gfx/SDL_gfxPrimitives.c``). They are the largest cost of a frame: the anti-aliased
outline blends each pixel through a chain of per-pixel function calls. The functions here
replay the same integer algorithms, compiled with numba, on a ``(height, width)`` uint32 view of
a 32-bit surface (the transpose of ``pygame.surfarray.pixels2d``):

* ``aapolygonColor``: one ``_aalineColor`` per edge without its end point: the line is clipped
  to the surface with ``_clipLine`` (float32 slopes, truncation to ``Sint16``), horizontal and
  vertical lines are drawn opaque, others with Wu's algorithm (a 32-bit error accumulator, 8-bit
  weights); a weighted pixel blends as ``_putPixelAlpha``'s default 32-bit routine does
  (``d + floor((s - d) * a / 256)`` per channel, ``a = 255 * weight >> 8``).
* ``filledPolygonColorMT``: a scanline fill with 16.16 fixed-point edge intersections, rounded
  as SDL_gfx rounds them, sorted, and filled pairwise with ``hlineColor``'s swap and clip (note
  its min/max ``else if``, reproduced).

``safe_bc.tasks.carracing.fast_render`` checks these against pygame on random polygons once
per process (:func:`matches_pygame`) and keeps pygame's own calls if they ever disagree, so a
pygame-ce release that changes its drawing cannot change a frame.
``tests/tasks/carracing/test_gfx_kernels.py`` compares them pixel for pixel, and
``tests/tasks/carracing/test_fast_render.py`` whole frames with stock.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["draw_polygons", "matches_pygame"]

_LEFT, _RIGHT, _BOTTOM, _TOP = 1, 2, 4, 8
_MASK32 = 0xFFFFFFFF


@njit(cache=True, inline="always")
def _encode(x: int, y: int, right: int, bottom: int) -> int:
    code = 0
    if x < 0:
        code |= _LEFT
    elif x > right:
        code |= _RIGHT
    if y < 0:
        code |= _TOP
    elif y > bottom:
        code |= _BOTTOM
    return code


@njit(cache=True)
def _sint16(v: int) -> int:
    """C's conversion of an int to ``Sint16`` (wraps)."""
    return ((v + 32768) & 0xFFFF) - 32768


@njit(cache=True)
def _clip_line(
    x1: int, y1: int, x2: int, y2: int, right: int, bottom: int
) -> tuple[bool, int, int, int, int]:
    """SDL_gfx ``_clipLine`` against ``[0, right] x [0, bottom]``; float32 slope as in C."""
    while True:
        c1 = _encode(x1, y1, right, bottom)
        c2 = _encode(x2, y2, right, bottom)
        if (c1 | c2) == 0:
            return True, x1, y1, x2, y2
        if c1 & c2:
            return False, x1, y1, x2, y2
        if c1 == 0:
            x1, x2 = x2, x1
            y1, y2 = y2, y1
            c1, c2 = c2, c1
        m = np.float32(y2 - y1) / np.float32(x2 - x1) if x2 != x1 else np.float32(1.0)
        if c1 & _LEFT:
            y1 = _sint16(y1 + int(np.float32(0 - x1) * m))
            x1 = 0
        elif c1 & _RIGHT:
            y1 = _sint16(y1 + int(np.float32(right - x1) * m))
            x1 = right
        elif c1 & _BOTTOM:
            if x2 != x1:
                x1 = _sint16(x1 + int(np.float32(bottom - y1) / m))
            y1 = bottom
        elif c1 & _TOP:
            if x2 != x1:
                x1 = _sint16(x1 + int(np.float32(0 - y1) / m))
            y1 = 0


@njit(cache=True, inline="always")
def _blend(pix: np.ndarray, x: int, y: int, color: int, weight: int, top: int) -> None:
    """``pixelColorWeightNolock``: blend ``color`` (0x00RRGGBB) at alpha ``255*weight >> 8``."""
    h, w = pix.shape
    if x < 0 or x >= w or y < top or y >= h:
        return
    a = (255 * weight) >> 8
    d = np.int64(pix[y, x])
    r = (d >> 16) & 255
    g = (d >> 8) & 255
    b = d & 255
    r += ((((color >> 16) & 255) - r) * a) >> 8
    g += ((((color >> 8) & 255) - g) * a) >> 8
    b += (((color & 255) - b) * a) >> 8
    pix[y, x] = np.uint32((r << 16) | (g << 8) | b)


@njit(cache=True, inline="always")
def _put(pix: np.ndarray, x: int, y: int, mapped: int, top: int) -> None:
    h, w = pix.shape
    if 0 <= x < w and top <= y < h:
        pix[y, x] = np.uint32(mapped)


@njit(cache=True)
def _hline(pix: np.ndarray, x1: int, x2: int, y: int, mapped: int, top: int) -> None:
    """``hlineColor`` with an opaque colour: swap, clip, fill ``x1..x2`` inclusive."""
    h, w = pix.shape
    if x1 > x2:
        x1, x2 = x2, x1
    if x2 < 0 or x1 > w - 1 or y < top or y > h - 1:
        return
    x1 = max(x1, 0)
    x2 = min(x2, w - 1)
    pix[y, x1 : x2 + 1] = np.uint32(mapped)


@njit(cache=True)
def _vline(pix: np.ndarray, x: int, y1: int, y2: int, mapped: int, top: int) -> None:
    """``vlineColor`` with an opaque colour."""
    h, w = pix.shape
    if y1 > y2:
        y1, y2 = y2, y1
    if x < 0 or x > w - 1 or y2 < 0 or y1 > h - 1:
        return
    y1 = max(y1, top)
    y2 = min(y2, h - 1)
    value = np.uint32(mapped)
    for y in range(y1, y2 + 1):
        pix[y, x] = value


@njit(cache=True)
def _aaline(pix: np.ndarray, x1: int, y1: int, x2: int, y2: int, color: int, top: int) -> None:
    """``_aalineColor(..., draw_endpoint=0)`` with an opaque ``color`` (0x00RRGGBB, which is
    also its mapped pixel value in pygame's default 32-bit format)."""
    h, w = pix.shape
    ok, x1, y1, x2, y2 = _clip_line(x1, y1, x2, y2, w - 1, h - 1)
    if not ok:
        return
    xx0, yy0, xx1, yy1 = x1, y1, x2, y2
    if yy0 > yy1:
        xx0, xx1 = xx1, xx0
        yy0, yy1 = yy1, yy0
    dx = xx1 - xx0
    dy = yy1 - yy0
    if dx == 0:
        if dy > 0:
            _vline(pix, x1, yy0, yy0 + dy, color, top)
        else:
            _put(pix, x1, y1, color, top)
        return
    if dy == 0:
        _hline(pix, xx0, xx0 + dx, y1, color, top)
        return
    xdir = 1
    if dx < 0:
        xdir = -1
        dx = -dx
    erracc = 0
    _put(pix, x1, y1, color, top)
    if dy > dx:
        erradj = ((dx << 16) // dy << 16) & _MASK32
        x0pxdir = xx0 + xdir
        for _ in range(dy - 1):
            previous = erracc
            erracc = (erracc + erradj) & _MASK32
            if erracc <= previous:
                xx0 = x0pxdir
                x0pxdir += xdir
            yy0 += 1
            wgt = (erracc >> 24) & 255
            _blend(pix, xx0, yy0, color, 255 - wgt, top)
            _blend(pix, x0pxdir, yy0, color, wgt, top)
    else:
        erradj = ((dy << 16) // dx << 16) & _MASK32
        y0p1 = yy0 + 1
        for _ in range(dx - 1):
            previous = erracc
            erracc = (erracc + erradj) & _MASK32
            if erracc <= previous:
                yy0 = y0p1
                y0p1 += 1
            xx0 += xdir
            wgt = (erracc >> 24) & 255
            _blend(pix, xx0, yy0, color, 255 - wgt, top)
            _blend(pix, xx0, y0p1, color, wgt, top)


@njit(cache=True)
def _filled_polygon(
    pix: np.ndarray, vx: np.ndarray, vy: np.ndarray, mapped: int, top: int, ints: np.ndarray
) -> None:
    """``filledPolygonColorMT`` with an opaque colour (rows above ``top`` skipped)."""
    n = vx.shape[0]
    h = pix.shape[0]
    miny = vy[0]
    maxy = vy[0]
    for i in range(1, n):
        if vy[i] < miny:
            miny = vy[i]
        elif vy[i] > maxy:  # SDL_gfx's ``else if``: kept as is
            maxy = vy[i]
    for y in range(max(miny, top), min(maxy, h - 1) + 1):
        count = 0
        for i in range(n):
            ind1 = n - 1 if i == 0 else i - 1
            ind2 = i
            y1 = vy[ind1]
            y2 = vy[ind2]
            if y1 < y2:
                x1 = vx[ind1]
                x2 = vx[ind2]
            elif y1 > y2:
                y2 = vy[ind1]
                y1 = vy[ind2]
                x2 = vx[ind1]
                x1 = vx[ind2]
            else:
                continue
            if (y1 <= y < y2) or (y == maxy and y1 < y <= y2):
                value = (65536 * (y - y1)) // (y2 - y1) * (x2 - x1) + 65536 * x1
                value = ((value + 2**31) & _MASK32) - 2**31  # C int arithmetic
                j = count  # insertion sort (qsort's order for distinct keys; ties are equal)
                while j > 0 and ints[j - 1] > value:
                    ints[j] = ints[j - 1]
                    j -= 1
                ints[j] = value
                count += 1
        for i in range(0, count - 1, 2):
            xa = ints[i] + 1
            xa = (xa >> 16) + ((xa & 32768) >> 15)
            xb = ints[i + 1] - 1
            xb = (xb >> 16) + ((xb & 32768) >> 15)
            _hline(pix, _sint16(xa), _sint16(xb), y, mapped, top)


@njit(cache=True)
def draw_polygons(
    pix: np.ndarray, vx: np.ndarray, vy: np.ndarray, colors: np.ndarray, top: int
) -> None:
    """Stock's track drawing: for each polygon in order, ``aapolygon`` then ``filled_polygon``.

    Args:
        pix: ``(height, width)`` uint32 pixels of a 32-bit surface with 8-bit R, G, B at bits
            16, 8 and 0 (pygame's default format), drawn on in place: the transpose of
            ``pygame.surfarray.pixels2d``, C-contiguous when the surface has no row padding.
        vx, vy: ``(D, K)`` int64 vertices, already converted as gfxdraw converts them (truncated
            towards zero, then to ``Sint16``).
        colors: ``(D,)`` int64 colours ``0x00RRGGBB`` (opaque).
        top: rows above it are left untouched (they are painted over later); every other pixel
            is exactly what the two pygame calls would leave.
    """
    ints = np.empty(vx.shape[1], np.int64)
    for d in range(vx.shape[0]):
        color = colors[d]
        k = vx.shape[1]
        for i in range(1, k):
            _aaline(pix, vx[d, i - 1], vy[d, i - 1], vx[d, i], vy[d, i], color, top)
        _aaline(pix, vx[d, k - 1], vy[d, k - 1], vx[d, 0], vy[d, 0], color, top)
        _filled_polygon(pix, vx[d], vy[d], color, top, ints)


def matches_pygame(trials: int = 60, seed: int = 0) -> bool:
    """True if :func:`draw_polygons` draws what pygame's ``gfxdraw`` draws, pixel for pixel,
    for ``trials`` random quads (convex and not, partly off-surface, thin, axis-aligned) on a
    noisy background."""
    import pygame
    from pygame import gfxdraw

    rng = np.random.default_rng(seed)
    size = (160, 120)
    for t in range(trials):
        background = rng.integers(0, 256, size=(size[0], size[1], 3), dtype=np.uint8)
        surf = pygame.Surface(size)
        pygame.surfarray.blit_array(surf, background)
        ours = np.ascontiguousarray(pygame.surfarray.array2d(surf).astype(np.uint32).T)
        span = 400 if t % 3 == 0 else 180
        quad = rng.integers(-span // 2, span, size=(4, 2))
        if t % 5 == 0:
            quad[1, 1] = quad[0, 1]  # a horizontal edge
            quad[3, 0] = quad[2, 0]  # a vertical edge
        color = tuple(int(c) for c in rng.integers(0, 256, size=3))
        gfxdraw.aapolygon(surf, quad.tolist(), color)
        gfxdraw.filled_polygon(surf, quad.tolist(), color)
        packed = np.array([(color[0] << 16) | (color[1] << 8) | color[2]], np.int64)
        draw_polygons(
            ours, quad[None, :, 0].astype(np.int64), quad[None, :, 1].astype(np.int64), packed, 0
        )
        theirs = pygame.surfarray.array2d(surf).astype(np.uint32).T & 0xFFFFFF
        if not np.array_equal(ours & 0xFFFFFF, theirs):
            return False
    return True
