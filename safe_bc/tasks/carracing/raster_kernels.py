"""The raster renderer's vertex transforms, compiled (numba).

:class:`~safe_bc.tasks.carracing.raster_render.RasterCarRacing` moves ~40 track polygons and
~12 car polygons per frame from the world to the canvas; in numpy that is dozens of calls on
arrays of 4 to 40 elements, each paying numpy's per-call overhead. These kernels do the same
in one call each, with the same float64 operations in the same order (numba's defaults do not
reassociate; :func:`self_check` would catch a compiler that fused a multiply-add), so every
fixed-point vertex handed to ``cv2.fillPoly`` is the one the numpy expressions give:

* :func:`track_points`: the exact renderer's culling (a disc test around the visible area,
  then stock's vertex-in-window test and the bounding-box test against the kept rows, as
  ``FastCarRacing._near_polygons`` and ``_visible_polygons`` compute them) and the canvas
  vertices of the polygons kept, in stock's order;
* :func:`car_points`: body-local vertices moved by their body's rotation and position, then
  the camera's, then to the canvas.

The canvas mapping is ``X = round((x * sx - 0.5) * 16)``, ``Y = round(((800 - y) * sy - 0.5)
* 16)`` (round half to even, as ``ndarray.round``). A vertex beyond int32 (never seen: it
would take a polygon ~1e7 px off screen) makes a kernel return -1 and the renderer use numpy.

:func:`self_check` compares both with the numpy expressions on random inputs once per process
(:func:`safe_bc.tasks.carracing.compiled.load_kernels`); ``tests/tasks/carracing/
test_raster_identity.py`` compares whole episodes with the implementation the committed
results used.
"""

from __future__ import annotations

import numpy as np
from gymnasium.envs.box2d.car_racing import MAX_SHAPE_DIM, WINDOW_H, WINDOW_W
from numba import njit

__all__ = ["car_points", "self_check", "track_points"]

_SQRT2 = np.sqrt(2.0) * (1.0 + 1e-9)  # fast_render._SQRT2
_SKIP_MARGIN = 3.0  # fast_render._SKIP_MARGIN
_INT32_LIMIT = 2147483647.0
_LO = -MAX_SHAPE_DIM
_HI_X = WINDOW_W + MAX_SHAPE_DIM
_HI_Y = WINDOW_H + MAX_SHAPE_DIM
_KEEP_LO = -_SKIP_MARGIN
_KEEP_X = WINDOW_W + _SKIP_MARGIN
_KEEP_Y = WINDOW_H + _SKIP_MARGIN
_H = float(WINDOW_H)


@njit(cache=True, inline="always")
def _fixed(px: float, py: float, sx: float, sy: float, out: np.ndarray, row: int) -> bool:
    """Canvas fixed point of screen ``(px, py)`` into ``out[row]``; False beyond int32."""
    x = np.rint((px * sx - 0.5) * 16.0)
    y = np.rint(((_H - py) * sy - 0.5) * 16.0)
    if not (abs(x) <= _INT32_LIMIT and abs(y) <= _INT32_LIMIT):
        return False
    out[row, 0] = np.int32(x)
    out[row, 1] = np.int32(y)
    return True


@njit(cache=True)
def track_points(
    xy: np.ndarray,
    centre: np.ndarray,
    radius: np.ndarray,
    view: np.ndarray,
    visible_top: float,
    out: np.ndarray,
    index: np.ndarray,
) -> int:
    """Canvas vertices of the track polygons that can reach a kept pixel, in order.

    Args:
        xy: ``(N, 4, 2)`` float64 world vertices (grass squares, then the road).
        centre, radius: ``(N, 2)`` world centres and ``(N,)`` radii of the polygons.
        view: float64 ``[c, s, zoom, tx, ty, kx, ky, reach, sx, sy]``: the camera's rotation,
            zoom and translation, the world point under the kept area's centre and
            ``(reach + 2) / zoom`` (``FastCarRacing._near_polygons``), the canvas scales.
        visible_top: the first kept screen row.
        out: ``(N, 4, 2)`` int32, the kept polygons' canvas vertices written to
            ``out[:count]``.
        index: ``(N,)`` int64, their indices written to ``index[:count]``.

    Returns:
        ``count``, or -1 if a vertex does not fit int32 (``out`` is then unusable).
    """
    c, s, zoom, tx, ty, kx, ky, reach, sx, sy = (
        view[0],
        view[1],
        view[2],
        view[3],
        view[4],
        view[5],
        view[6],
        view[7],
        view[8],
        view[9],
    )
    keep_top = visible_top - _SKIP_MARGIN
    px = np.empty(4)
    py = np.empty(4)
    count = 0
    for i in range(xy.shape[0]):
        limit = radius[i] * _SQRT2 + reach
        dx = centre[i, 0] - kx
        dy = centre[i, 1] - ky
        if not (dx * dx + dy * dy <= limit * limit):
            continue
        inside = False
        for k in range(4):
            x = xy[i, k, 0]
            y = xy[i, k, 1]
            px[k] = (c * x - s * y) * zoom + tx
            py[k] = (s * x + c * y) * zoom + ty
            if px[k] >= _LO and px[k] <= _HI_X and py[k] >= _LO and py[k] <= _HI_Y:
                inside = True
        if not inside:
            continue
        if not (
            px.max() >= _KEEP_LO
            and px.min() <= _KEEP_X
            and py.max() >= keep_top
            and py.min() <= _KEEP_Y
        ):
            continue
        poly = out[count]
        for k in range(4):
            if not _fixed(px[k], py[k], sx, sy, poly, k):
                return -1
        index[count] = i
        count += 1
    return count


@njit(cache=True)
def car_points(
    local: np.ndarray,
    body: np.ndarray,
    cos: np.ndarray,
    sin: np.ndarray,
    pos: np.ndarray,
    view: np.ndarray,
    count: int,
    out: np.ndarray,
) -> bool:
    """Canvas vertices of the first ``count`` body-local vertices.

    Args:
        local: ``(V, 2)`` float64 body-local vertices; ``body``: ``(V,)`` int64 their bodies.
        cos, sin: ``(B,)`` float64 the bodies' ``np.cos`` / ``np.sin`` of their angles.
        pos: ``(B, 2)`` float64 the bodies' world positions.
        view: float64 ``[c, s, zoom, tx, ty, ..., sx, sy]`` as for :func:`track_points`.
        out: ``(V, 2)`` int32, written to ``out[:count]``.

    Returns:
        False if a vertex does not fit int32 (``out`` is then unusable).
    """
    c, s, zoom, tx, ty, sx, sy = view[0], view[1], view[2], view[3], view[4], view[8], view[9]
    for v in range(count):
        b = body[v]
        lx = local[v, 0]
        ly = local[v, 1]
        wx = cos[b] * lx - sin[b] * ly + pos[b, 0]
        wy = sin[b] * lx + cos[b] * ly + pos[b, 1]
        px = (c * wx - s * wy) * zoom + tx
        py = (s * wx + c * wy) * zoom + ty
        if not _fixed(px, py, sx, sy, out, v):
            return False
    return True


def _numpy_fixed(px: np.ndarray, py: np.ndarray, sx: float, sy: float) -> np.ndarray:
    """The renderer's numpy canvas mapping (``RasterCarRacing._canvas_points``)."""
    x = (px * sx - 0.5) * 16
    y = ((WINDOW_H - py) * sy - 0.5) * 16
    return np.stack([x, y], axis=-1).round().astype(np.int32)


def self_check(trials: int = 40, seed: int = 0) -> bool:
    """True if both kernels give the numpy expressions' vertices on random polygons, bodies
    and cameras (and keep the same polygons as the numpy culling)."""
    rng = np.random.default_rng(seed)
    for _ in range(trials):
        xy = rng.uniform(-300.0, 300.0, (200, 4, 2))
        centre = xy.mean(axis=1)
        radius = np.sqrt(((xy - centre[:, None, :]) ** 2).sum(axis=2)).max(axis=1)
        c, s = np.cos(a := rng.uniform(0, 6.3)), np.sin(a)
        zoom = rng.uniform(1.0, 20.0)
        tx, ty = rng.uniform(-2000.0, 2000.0, 2)
        sx, sy = 0.192, 0.24
        kx, ky = rng.uniform(-100.0, 100.0, 2)
        reach = (rng.uniform(500.0, 700.0) + 2.0) / zoom
        view = np.array([c, s, zoom, tx, ty, kx, ky, reach, sx, sy])
        out = np.empty((200, 4, 2), np.int32)
        index = np.empty(200, np.int64)
        count = track_points(xy, centre, radius, view, 100.0, out, index)
        dx, dy = centre[:, 0] - kx, centre[:, 1] - ky
        limit = radius * _SQRT2 + reach
        near = np.flatnonzero(dx * dx + dy * dy <= limit * limit)
        px = (c * xy[near, :, 0] - s * xy[near, :, 1]) * zoom + tx
        py = (s * xy[near, :, 0] + c * xy[near, :, 1]) * zoom + ty
        inside = ((px >= _LO) & (px <= _HI_X) & (py >= _LO) & (py <= _HI_Y)).any(axis=1)
        touches = (
            inside
            & (px.max(axis=1) >= _KEEP_LO)
            & (px.min(axis=1) <= _KEEP_X)
            & (py.max(axis=1) >= 100.0 - _SKIP_MARGIN)
            & (py.min(axis=1) <= _KEEP_Y)
        )
        want = _numpy_fixed(px[touches], py[touches], sx, sy)
        if count != len(want) or not np.array_equal(index[:count], near[touches]):
            return False
        if not np.array_equal(out[:count], want):
            return False
        local = rng.uniform(-2.0, 2.0, (40, 2))
        body = rng.integers(0, 5, 40)
        angle = rng.uniform(-20.0, 20.0, 5)
        cos, sin = np.cos(angle), np.sin(angle)
        pos = rng.uniform(-300.0, 300.0, (5, 2))
        car = np.empty((40, 2), np.int32)
        if not car_points(local, body, cos, sin, pos, view, 40, car):
            return False
        wx = cos[body] * local[:, 0] - sin[body] * local[:, 1] + pos[body, 0]
        wy = sin[body] * local[:, 0] + cos[body] * local[:, 1] + pos[body, 1]
        want = _numpy_fixed((c * wx - s * wy) * zoom + tx, (s * wx + c * wy) * zoom + ty, sx, sy)
        if not np.array_equal(car, want):
            return False
    return True
