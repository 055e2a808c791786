"""Safety distances of the car from the grass, read off a CarRacing frame.

Pure numpy, no gym, no I/O (the rays also have a compiled twin, :mod:`.ray_kernel`, with
the same float32 results, used where numba is installed). The camera of ``CarRacing-v3``
follows the car and rotates with it, so the car is always drawn pointing up at the same place
of the 96x96 state (hull rows 67-76, cols 46-49; wheels out to cols 45-50). From there we
cast three rays over the road and measure, in pixels, how much road lies between
the car's body and the grass:

* ``left``: along the car's rows, from column 44 towards column 0 (at most 45 px);
* ``right``: along the car's rows, from column 51 towards column 95 (at most 45 px);
* ``front``: along the car's columns, from row 65 towards row 0 (at most 66 px).

Each pixel gets a *greenness* ``g = clip((G - max(R, B)) / 100, 0, 1)``: 0 on the
grey road, the curbs and the car, ~1 on grass (~(100, 202, 100) and (100, 228, 100)).
A ray stops at the first pixel with ``g >= 0.5``; its distance is the sum of the
road fractions ``1 - g`` up to and including that pixel, so the anti-aliased edge
pixel left by the smooth-scaling contributes a sub-pixel fraction. The distance
of a side is the mean over the rows (columns) of the car's band. A car on the
grass has distance ~0 on that side.

Costs turn distances into "higher is less safe": ``cost = max_range - distance``,
so the paper's threshold ``d_s = max c_s`` is the closest the expert came to the
grass, and ``c_s >= d_s - eps`` means "within eps pixels of that".
"""

from __future__ import annotations

from typing import Any

import numpy as np

from safe_bc.data.episode import SAFETY_DIMS

__all__ = ["MAX_RANGE", "SAFETY_DIMS", "costs_from_distances", "greenness", "pixel_distances"]

CAR_ROWS = slice(66, 78)
"""Rows of the car (wheels included) used for the side rays."""
CAR_COLS = slice(45, 51)
"""Columns of the car (wheels included) used for the front ray."""
LEFT_START, RIGHT_START, FRONT_START = 44, 51, 65
"""First pixel outside the car on each ray."""

MAX_RANGE: np.ndarray = np.array([LEFT_START + 1, FRONT_START + 1, 96 - RIGHT_START], np.float32)
"""``(3,)`` the longest measurable distance per dimension (45, 66, 45 px)."""

GRASS_LEVEL = 0.5
"""Greenness at which a ray stops."""


def greenness(frame: np.ndarray) -> np.ndarray:
    """Per-pixel grass score in [0, 1].

    Args:
        frame: ``(H, W, 3) uint8`` RGB.

    Returns:
        ``(H, W) float32``.
    """
    f = frame.astype(np.int16)
    excess = f[..., 1] - np.maximum(f[..., 0], f[..., 2])
    return np.clip(excess.astype(np.float32) / 100.0, 0.0, 1.0)


def _ray_distance(green: np.ndarray) -> np.ndarray:
    """Distance along the last axis of ``green`` ``(K, L)`` (pixel 0 next to the car).

    Returns ``(K,) float32``: sum of road fractions up to and including the first
    grass pixel, or over the whole ray when it never meets grass.
    """
    road = 1.0 - green
    csum = np.cumsum(road, axis=1)
    hit = green >= GRASS_LEVEL
    any_hit = hit.any(axis=1)
    first = np.where(any_hit, hit.argmax(axis=1), green.shape[1] - 1)
    return csum[np.arange(len(csum)), first].astype(np.float32)


def pixel_distances(frame: np.ndarray) -> np.ndarray:
    """Road pixels between the car and the grass, to the left, front and right.

    Args:
        frame: ``(96, 96, 3) uint8`` CarRacing state (after the zoom-in phase).

    Returns:
        ``(3,) float32`` distances in pixels, ordered as :data:`SAFETY_DIMS`.

    >>> frame = np.zeros((96, 96, 3), np.uint8); frame[..., 1] = 202  # all grass
    >>> frame[:, 30:70] = 102                                          # a road
    >>> pixel_distances(frame).round(1).tolist()
    [15.0, 66.0, 19.0]
    """
    if frame.shape != (96, 96, 3):
        raise ValueError(f"expected a (96, 96, 3) CarRacing frame, got shape {frame.shape}")
    if frame.dtype == np.uint8:
        kernel = _RayKernel.module if _RayKernel.resolved else _RayKernel.resolve()
        if kernel is not None:
            return kernel.distances(frame)
    return _numpy_distances(frame)


class _RayKernel:
    """:mod:`.ray_kernel` (the same distances, compiled) where it may be used, else None
    (:func:`safe_bc.tasks.carracing.compiled.load_kernels`), resolved on first use."""

    module: Any = None
    resolved = False

    @classmethod
    def resolve(cls) -> Any:
        from safe_bc.tasks.carracing.compiled import load_kernels

        cls.module = load_kernels("ray_kernel")
        cls.resolved = True
        return cls.module


def _numpy_distances(frame: np.ndarray) -> np.ndarray:
    """:func:`pixel_distances` in numpy (the definition :mod:`.ray_kernel` reproduces)."""
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


def frame_costs(frames: np.ndarray) -> np.ndarray:
    """Safety costs of a batch of frames ``(B, 96, 96, 3) -> (B, 3) float64``: exactly the
    env's costs, which are defined on the frame."""
    return np.stack([costs_from_distances(pixel_distances(f)) for f in frames]).astype(float)


def costs_from_distances(distances: np.ndarray) -> np.ndarray:
    """Safety costs ``MAX_RANGE - distance`` (higher is less safe).

    Args:
        distances: ``(..., 3)`` pixel distances.

    Returns:
        ``(..., 3) float32`` costs in ``[0, MAX_RANGE]``.

    >>> costs_from_distances(np.array([45.0, 0.0, 40.0])).tolist()
    [0.0, 66.0, 5.0]
    """
    # np.clip(distances, 0.0, MAX_RANGE) as two ufuncs (np.clip's Python wrapper costs more
    # than the work): the same values, NaN included; a -0.0 may keep its sign, which the
    # subtraction ignores
    clipped = np.minimum(np.maximum(distances, 0.0), MAX_RANGE)
    return (MAX_RANGE - clipped).astype(np.float32)
