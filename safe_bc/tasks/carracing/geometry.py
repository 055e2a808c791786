"""Pure track geometry for CarRacing (no env, no Box2D).

Conventions (CarRacing-v3, gymnasium 1.4):

* A track is an ``(N, 4)`` array of centre-line points ``(alpha, beta, x, y)``,
  ordered in the driving direction, about 3.5 units apart; ``beta`` is the heading.
* The travel direction at point ``i`` is ``(-sin beta_i, cos beta_i)`` and the
  cross-track direction is ``(cos beta_i, sin beta_i)``, which points to the
  **right** of the travel direction (the road tile's ``road_r`` edge).
* The car's right is ``+steer`` (action ``[+1, ., .]`` turns right), and the car's
  own right is ``(cos angle, sin angle)`` for hull angle ``angle``.

So a positive lateral offset means "right of the centre line, seen in the driving
direction", the side a positive steer turns towards.
"""

from __future__ import annotations

import numpy as np

ROAD_HALF_WIDTH: float = 40.0 / 6.0
"""Half-width of the road (``TRACK_WIDTH`` in ``car_racing.py``), world units."""

CAR_HALF_WIDTH: float = 1.38
"""Lateral distance from the hull centre to the outer edge of a wheel (units)."""


def nearest_track_index(track: np.ndarray, position: np.ndarray) -> int:
    """Index of the track point closest to ``position``.

    Args:
        track: ``(N, 4)`` centre-line points ``(alpha, beta, x, y)``.
        position: ``(2,)`` world ``(x, y)``.
    """
    track = np.asarray(track, dtype=np.float64)
    d = track[:, 2:4] - np.asarray(position, dtype=np.float64)[:2]
    return int(np.argmin(np.einsum("ij,ij->i", d, d)))


def lateral_offset(track: np.ndarray, position: np.ndarray) -> float:
    """Signed distance of ``position`` from the centre line, world units.

    Positive is to the right of the centre line in the driving direction
    (the side ``+steer`` turns towards), negative to the left. The offset is the
    projection of ``position - p_i`` on the cross-track direction
    ``(cos beta_i, sin beta_i)`` of the nearest centre-line point ``p_i``.
    The road edge is at ``|offset| == ROAD_HALF_WIDTH`` (~6.67).

    Args:
        track: ``(N, 4)`` centre-line points ``(alpha, beta, x, y)``.
        position: ``(2,)`` world ``(x, y)``.

    >>> track = np.array([[0.0, 0.0, 0.0, float(y)] for y in range(10)])  # heading +y
    >>> lateral_offset(track, np.array([2.0, 4.2]))  # +x is right when driving +y
    2.0
    >>> lateral_offset(track, np.array([-1.5, 7.0]))
    -1.5
    """
    track = np.asarray(track, dtype=np.float64)
    pos = np.asarray(position, dtype=np.float64)[:2]
    i = nearest_track_index(track, pos)
    beta = track[i, 1]
    d = pos - track[i, 2:4]
    return float(d[0] * np.cos(beta) + d[1] * np.sin(beta))


def lateral_offsets(track: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Vectorised :func:`lateral_offset`: ``(T, 2)`` positions -> ``(T,)`` float64."""
    track = np.asarray(track, dtype=np.float64)
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
    d = pos[:, None, :] - track[None, :, 2:4]  # (T, N, 2)
    i = np.argmin(np.einsum("tnk,tnk->tn", d, d), axis=1)
    beta = track[i, 1]
    dd = pos - track[i, 2:4]
    return dd[:, 0] * np.cos(beta) + dd[:, 1] * np.sin(beta)
