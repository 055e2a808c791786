"""The safety rays of :func:`safe_bc.tasks.carracing.costs.pixel_distances`, compiled (numba).

The numpy version spends ~40 us a frame on small-array overhead (gathering ~(30, 66) ray
pixels, a cumulative sum, argmax, three means). Here each ray is walked pixel by pixel with
the same float32 operations in the same order, so the distances are equal bit for bit:

* greenness ``min(max(float32(G - max(R, B)) / 100, 0), 1)``, road fraction ``1 - g``;
* a ray's distance is its running float32 sum of road fractions, stopped at (and including)
  the first pixel with ``g >= 0.5``, as ``np.cumsum`` accumulates (one element after another);
* a side's distance is the float32 mean over its rays as ``ndarray.mean`` computes it: numpy's
  pairwise sum (fewer than 8 values: one after another; 8 to 128: eight running sums over
  the first multiple of 8 values, combined as ``((s0 + s1) + (s2 + s3)) + ((s4 + s5) +
  (s6 + s7))``, then the rest one by one), divided by the count.

:func:`self_check` compares it with the numpy version on random frames once per process
(:func:`safe_bc.tasks.carracing.compiled.load_kernels`); ``tests/tasks/carracing/
test_raster_identity.py`` compares both with the implementation the committed results used.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from safe_bc.tasks.carracing.costs import (
    CAR_COLS,
    CAR_ROWS,
    FRONT_START,
    GRASS_LEVEL,
    LEFT_START,
    RIGHT_START,
)

__all__ = ["distances", "self_check"]

_ROW0, _ROW1 = CAR_ROWS.start, CAR_ROWS.stop
_COL0, _COL1 = CAR_COLS.start, CAR_COLS.stop
_LEFT_LEN = LEFT_START + 1  # 45 px, cols LEFT_START .. 0
_RIGHT_LEN = 96 - RIGHT_START  # 45 px, cols RIGHT_START .. 95
_FRONT_LEN = FRONT_START + 1  # 66 px, rows FRONT_START .. 0
_HUNDRED = np.float32(100.0)
_ONE = np.float32(1.0)
_ZERO = np.float32(0.0)
_LEVEL = np.float32(GRASS_LEVEL)


@njit(cache=True, inline="always")
def _green(frame: np.ndarray, r: int, c: int) -> np.float32:
    red = np.int16(frame[r, c, 0])
    green = np.int16(frame[r, c, 1])
    blue = np.int16(frame[r, c, 2])
    g = np.float32(green - max(red, blue)) / _HUNDRED
    g = max(g, _ZERO)
    return min(g, _ONE)


@njit(cache=True)
def _ray(frame: np.ndarray, r: int, c: int, dr: int, dc: int, length: int) -> np.float32:
    """Road fractions summed from ``(r, c)`` in steps ``(dr, dc)`` up to and including the
    first grass pixel (or over ``length`` pixels)."""
    total = _ZERO
    for i in range(length):
        g = _green(frame, r + i * dr, c + i * dc)
        total = np.float32(total + (_ONE - g))
        if g >= _LEVEL:
            break
    return total


@njit(cache=True)
def _mean(values: np.ndarray) -> np.float32:
    """``values.mean()`` of a float32 vector of at most 128 values, bit for bit."""
    n = values.shape[0]
    if n < 8:
        total = _ZERO
        for i in range(n):
            total = np.float32(total + values[i])
    else:
        s = values[:8].copy()
        i = 8
        full = n - n % 8
        while i < full:
            for k in range(8):
                s[k] = np.float32(s[k] + values[i + k])
            i += 8
        total = np.float32(
            np.float32(np.float32(s[0] + s[1]) + np.float32(s[2] + s[3]))
            + np.float32(np.float32(s[4] + s[5]) + np.float32(s[6] + s[7]))
        )
        while i < n:
            total = np.float32(total + values[i])
            i += 1
    return np.float32(total / np.float32(n))


@njit(cache=True)
def distances(frame: np.ndarray) -> np.ndarray:
    """``(3,) float32`` left, front and right distances of a ``(96, 96, 3)`` uint8 frame,
    equal to ``costs._numpy_distances(frame)``."""
    left = np.empty(_ROW1 - _ROW0, np.float32)
    right = np.empty(_ROW1 - _ROW0, np.float32)
    front = np.empty(_COL1 - _COL0, np.float32)
    for k in range(_ROW1 - _ROW0):
        left[k] = _ray(frame, _ROW0 + k, LEFT_START, 0, -1, _LEFT_LEN)
        right[k] = _ray(frame, _ROW0 + k, RIGHT_START, 0, 1, _RIGHT_LEN)
    for k in range(_COL1 - _COL0):
        front[k] = _ray(frame, FRONT_START, _COL0 + k, -1, 0, _FRONT_LEN)
    out = np.empty(3, np.float32)
    out[0] = _mean(left)
    out[1] = _mean(front)
    out[2] = _mean(right)
    return out


def self_check(trials: int = 200, seed: int = 0) -> bool:
    """True if :func:`distances` equals the numpy version bit for bit on ``trials`` random
    frames (noise, and road/grass frames with blended edges)."""
    from safe_bc.tasks.carracing.costs import _numpy_distances

    rng = np.random.default_rng(seed)
    for t in range(trials):
        if t % 2:
            frame = rng.integers(0, 256, (96, 96, 3), dtype=np.uint8)
        else:
            frame = np.empty((96, 96, 3), np.uint8)
            frame[...] = (102, 230, 102)
            a, b = np.sort(rng.integers(0, 97, 2))
            frame[rng.integers(0, 70) :, a:b] = 102
            frame[rng.integers(0, 96, 60), rng.integers(0, 96, 60), 1] = rng.integers(100, 231, 60)
        if distances(frame).tobytes() != _numpy_distances(frame).tobytes():
            return False
    return True
