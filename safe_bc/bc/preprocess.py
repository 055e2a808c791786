"""Observations -> network inputs: crop, grayscale, resize, frame stacking. Pure functions.

Frames ``(B, H, W, 3) uint8`` become ``(B, C, H', W') float32`` in ``[0, 1]`` with
``C = (1 if grayscale else 3) * frame_stack``, frames oldest first along channels.
Vectors ``(B, D)`` become ``(B, D * frame_stack) float32`` (standardisation lives in the
model, so that its statistics travel with the weights).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
import torch.nn.functional as F

from safe_bc.bc.config import PreprocessConfig

BAR_ROWS = 12
"""Rows of the indicator bar at the bottom of a CarRacing frame (rows 84-95 of 96)."""

STEERING_INDICATOR = (slice(84, 96), slice(36, 62))
"""Rows and columns of a 96x96 CarRacing frame holding the steering-angle indicator (the
green bar centred on column 48; measured by steering hard left and right, it spans columns
38-58 at the wheels' lock); the speed, ABS and gyro indicators lie outside it."""

LUMA = (0.299, 0.587, 0.114)
"""ITU-R 601 RGB -> luma weights."""

_LUMA_ROW = torch.tensor([LUMA], dtype=torch.float32) / 255.0


def is_image(obs_shape: Sequence[int]) -> bool:
    """Whether one observation of this shape is an ``(H, W, 3)`` frame (else a ``(D,)`` vector)."""
    return len(obs_shape) == 3 and obs_shape[-1] == 3


def _check_obs_shape(obs_shape: Sequence[int]) -> None:
    if not (is_image(obs_shape) or len(obs_shape) == 1):
        raise ValueError(f"observations must be (H, W, 3) frames or (D,) vectors, got {obs_shape}")


def frame_shape(obs_shape: Sequence[int], cfg: PreprocessConfig) -> tuple[int, ...]:
    """Shape of one preprocessed observation before stacking: ``(C1, H', W')`` or ``(D,)``."""
    _check_obs_shape(obs_shape)
    if not is_image(obs_shape):
        return (int(obs_shape[0]),)
    h, w = int(obs_shape[0]), int(obs_shape[1])
    if cfg.crop_bar:
        if h <= BAR_ROWS:
            raise ValueError(f"cannot crop {BAR_ROWS} bar rows from frames of height {h}")
        h -= BAR_ROWS
    if cfg.resize is not None:
        h = w = cfg.resize
    return (1 if cfg.grayscale else 3, h, w)


def input_shape(obs_shape: Sequence[int], cfg: PreprocessConfig) -> tuple[int, ...]:
    """Network input shape per sample: ``(C1 * k, H', W')`` or ``(D * k,)``.

    >>> input_shape((96, 96, 3), PreprocessConfig(frame_stack=4, grayscale=True, crop_bar=True))
    (4, 84, 96)
    >>> input_shape((7,), PreprocessConfig(frame_stack=2))
    (14,)
    """
    first, *rest = frame_shape(obs_shape, cfg)
    return (first * cfg.frame_stack, *rest)


def preprocess_frames(frames: np.ndarray | torch.Tensor, cfg: PreprocessConfig) -> torch.Tensor:
    """``(B, H, W, 3) uint8 -> (B, C1, H', W') float32`` in ``[0, 1]`` (no stacking)."""
    x = torch.as_tensor(frames)
    if x.ndim != 4 or x.shape[-1] != 3 or x.dtype != torch.uint8:
        raise ValueError(
            f"frames must be (B, H, W, 3) uint8, got {tuple(x.shape)} {x.dtype}".replace(
                "torch.", ""
            )
        )
    if cfg.mask_steering and x.shape[1:3] != (96, 96):
        raise ValueError(f"mask_steering needs 96x96 CarRacing frames, got {tuple(x.shape)}")
    if cfg.crop_bar:  # the steering indicator lies in the bar: nothing left to mask
        x = x[:, : x.shape[1] - BAR_ROWS]
    if cfg.grayscale:
        # (B, H, W, 3) @ (3,) as a linear layer: the fastest CPU path; (B, H, W, 1) -> (B, 1, H, W)
        x = F.linear(x.float(), _LUMA_ROW).clamp_(0.0, 1.0).permute(0, 3, 1, 2)
    else:  # one copy to (B, 3, H, W) float32, scaled in place
        x = x.permute(0, 3, 1, 2).to(torch.float32, memory_format=torch.contiguous_format)
        x.div_(255.0)
    if cfg.mask_steering and not cfg.crop_bar:
        # black pixels (0 in every channel) give 0.0 whichever way they are converted, so
        # masking the converted frame equals masking the input, without copying the input
        x[:, :, STEERING_INDICATOR[0], STEERING_INDICATOR[1]] = 0.0
    if cfg.resize is not None:
        x = F.interpolate(x, size=(cfg.resize, cfg.resize), mode="area")
    return x.contiguous()


def preprocess(obs: np.ndarray | torch.Tensor, cfg: PreprocessConfig) -> torch.Tensor:
    """One observation per row, no stacking: frames via ``preprocess_frames``, vectors to
    ``(B, D) float32``."""
    x = torch.as_tensor(obs)
    if x.ndim == 4:
        return preprocess_frames(x, cfg)
    if x.ndim != 2:
        raise ValueError(f"observations must be (B, H, W, 3) or (B, D), got {tuple(x.shape)}")
    return x.to(torch.float32)


def stack(x: torch.Tensor, k: int) -> torch.Tensor:
    """``(B * k, C1, H, W) -> (B, k * C1, H, W)`` or ``(B * k, D) -> (B, k * D)``; rows are
    grouped per sample, oldest frame first."""
    if len(x) % k:
        raise ValueError(f"{len(x)} frames cannot be grouped in stacks of {k}")
    return x.reshape(len(x) // k, k * x.shape[1], *x.shape[2:])


def frame_stack_index(episode_ids: np.ndarray, steps: np.ndarray, k: int) -> np.ndarray:
    """Rows of the ``k`` frames ending at each row, oldest first: ``(N, k) int64``.

    The frame before row ``i`` is the row of the same episode with step ``steps[i] - 1``;
    where there is none (episode start) the earliest available frame is repeated.
    Rows need not be sorted; a repeated ``(episode, step)`` pair is an error.

    >>> frame_stack_index(np.array([0, 0, 0, 1, 1]), np.array([0, 1, 2, 0, 1]), 3).tolist()
    [[0, 0, 0], [0, 0, 1], [0, 1, 2], [3, 3, 3], [3, 3, 4]]
    """
    episode_ids = np.asarray(episode_ids, np.int64)
    steps = np.asarray(steps, np.int64)
    if episode_ids.shape != steps.shape or episode_ids.ndim != 1:
        raise ValueError(f"episode_ids {episode_ids.shape} and steps {steps.shape} must be (N,)")
    if k < 1:
        raise ValueError(f"k must be >= 1, got {k}")
    n = len(steps)
    order = np.lexsort((steps, episode_ids))
    e, s = episode_ids[order], steps[order]
    same = (e[1:] == e[:-1]) & (s[1:] == s[:-1])
    if same.any():
        j = int(np.flatnonzero(same)[0])
        raise ValueError(f"duplicate (episode_id, step) = ({e[j]}, {s[j]}): cannot stack frames")
    prev_sorted = np.arange(n)
    follows = (e[1:] == e[:-1]) & (s[1:] == s[:-1] + 1)
    prev_sorted[1:][follows] = np.arange(n - 1)[follows]
    prev = np.empty(n, np.int64)
    prev[order] = order[prev_sorted]
    out = np.empty((n, k), np.int64)
    out[:, k - 1] = np.arange(n)
    for j in range(k - 2, -1, -1):
        out[:, j] = prev[out[:, j + 1]]
    return out


def gather_inputs(
    observations: np.ndarray,
    rows: np.ndarray,
    cfg: PreprocessConfig,
    stack_index: np.ndarray | None = None,
) -> torch.Tensor:
    """Network inputs for ``rows (B,)`` of ``observations (N, ...)``; only these rows are
    preprocessed. ``stack_index (N, k)`` from ``frame_stack_index`` is required when
    ``cfg.frame_stack > 1``."""
    rows = np.asarray(rows, np.int64)
    k = cfg.frame_stack
    if k == 1:
        return preprocess(observations[rows], cfg)
    if stack_index is None or stack_index.shape[1] != k:
        raise ValueError(f"frame_stack={k} needs a (N, {k}) stack_index")
    idx = stack_index[rows].reshape(-1)
    return stack(preprocess(observations[idx], cfg), k)


def standardization_stats(
    observations: np.ndarray, valid: np.ndarray | None = None, min_std: float = 1e-6
) -> tuple[np.ndarray, np.ndarray]:
    """Per-feature ``(mean (D,), std (D,)) float32`` over valid rows of ``(N, D)`` vectors;
    a std below ``min_std`` (constant feature) becomes 1."""
    x = np.asarray(observations, np.float64)
    if x.ndim != 2:
        raise ValueError(f"standardization needs (N, D) vectors, got {x.shape}")
    if valid is not None:
        x = x[valid]
    if len(x) == 0:
        raise ValueError("no rows to compute standardization statistics from")
    mean, std = x.mean(axis=0), x.std(axis=0)
    std = np.where(std < min_std, 1.0, std)
    return mean.astype(np.float32), std.astype(np.float32)
