"""How CarRacing episodes are drawn (``safe-bc render``): the three safety rays of
:mod:`safe_bc.tasks.carracing.costs` over each frame, and the track seen from above.

The rays go from the first pixel outside the car (``LEFT_START``/``FRONT_START``/
``RIGHT_START``, centred on the car's rows or columns) to the distance measured in that
frame; :data:`DRAWING` is the task's :class:`~safe_bc.tasks.registry.Drawing`, which
:mod:`safe_bc.render` calls.
"""

from __future__ import annotations

from collections.abc import Sequence

import gymnasium as gym
import numpy as np

from safe_bc.tasks.carracing.costs import CAR_COLS, CAR_ROWS, FRONT_START, LEFT_START, RIGHT_START
from safe_bc.tasks.registry import Drawing

WHITE = (255, 255, 255)


def ray_segments(distances: np.ndarray) -> list[tuple[tuple[float, float], tuple[float, float]]]:
    """The three rays of :func:`safe_bc.tasks.carracing.costs.pixel_distances` as
    ``((x0, y0), (x1, y1))`` segments in frame coordinates (pixel ``i`` spans ``[i, i + 1)``),
    left/front/right.

    >>> [tuple(map(tuple, s)) for s in ray_segments(np.array([10.0, 20.0, 5.0]))]
    [((45.0, 72.0), (35.0, 72.0)), ((48.0, 66.0), (48.0, 46.0)), ((51.0, 72.0), (56.0, 72.0))]
    """
    row = (CAR_ROWS.start + CAR_ROWS.stop) / 2  # centre of the side rays' band of rows
    col = (CAR_COLS.start + CAR_COLS.stop) / 2  # centre of the front ray's band of columns
    left, front, right = (float(x) for x in distances)
    x_left, y_front, x_right = LEFT_START + 1.0, FRONT_START + 1.0, float(RIGHT_START)
    return [
        ((x_left, row), (x_left - left, row)),
        ((col, y_front), (col, y_front - front)),
        ((x_right, row), (x_right + right, row)),
    ]


def draw_rays(
    big: np.ndarray, distances: np.ndarray, colours: Sequence[tuple[int, int, int]], scale: int
) -> None:
    """Draw the rays of ``distances`` onto ``big`` (the frame upscaled ``scale`` times), in
    place, one colour per ray."""
    import cv2  # loaded on first drawing: registering the task imports no OpenCV

    shift = 4  # cv2 fixed-point: coordinates in 1/16 px

    def pt(x: float, y: float) -> tuple[int, int]:
        return round(x * scale * (1 << shift)), round(y * scale * (1 << shift))

    for (start, end), colour in zip(ray_segments(distances), colours, strict=True):
        cv2.line(big, pt(*start), pt(*end), colour, 2, cv2.LINE_AA, shift)
        cv2.circle(big, pt(*end), 4 << shift, colour, 2, cv2.LINE_AA, shift)
        cv2.circle(big, pt(*start), 2 << shift, WHITE, -1, cv2.LINE_AA, shift)


def caption(distances: np.ndarray) -> str:
    """The header's reading of one frame: ``L 10.0 F 20.0 R  5.0 px``."""
    left, front, right = (float(x) for x in distances)
    return f"L{left:4.1f} F{front:4.1f} R{right:4.1f} px"


def car_position(env: gym.Env) -> tuple[float, float]:
    """World coordinates of the car's hull."""
    pos = env.unwrapped.car.hull.position
    return float(pos[0]), float(pos[1])


def road(env: gym.Env) -> list[np.ndarray]:
    """The road tiles, ``(4, 2)`` world-coordinate polygons."""
    return [np.asarray(poly, np.float64) for poly, _ in env.unwrapped.road_poly]


DRAWING = Drawing(
    overlay=draw_rays,
    caption=caption,
    position=car_position,
    ground=road,
    unit="px",
    closest="px to the grass",
    scale_label="distance to grass (px, min L/F/R)",
)
"""CarRacing's entry in ``TaskSpec.drawing``."""
