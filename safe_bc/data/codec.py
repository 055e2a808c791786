"""Lossless observation encodings for the Parquet store (pure, no I/O)."""

from __future__ import annotations

from typing import Literal

import cv2
import numpy as np

Encoding = Literal["png", "raw", "vector"]
"""``png``: one PNG (RGB) per frame; ``raw``: the frame's bytes in C order (H, W, 3);
``vector``: a float32 list (non-image observations)."""


def encode_frames(frames: np.ndarray, encoding: Encoding) -> list[bytes]:
    """Encode ``(T, H, W, 3) uint8`` RGB frames, one ``bytes`` per frame.

    >>> f = np.random.default_rng(0).integers(0, 256, (2, 4, 4, 3), dtype=np.uint8)
    >>> bool((decode_frames(encode_frames(f, "png"), "png", (4, 4, 3)) == f).all())
    True
    """
    if frames.dtype != np.uint8 or frames.ndim != 4:
        raise ValueError(f"frames must be (T, H, W, 3) uint8, got {frames.shape} {frames.dtype}")
    if encoding == "raw":
        return [np.ascontiguousarray(f).tobytes() for f in frames]
    if encoding == "png":
        out = []
        for f in frames:
            ok, buf = cv2.imencode(".png", cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
            if not ok:
                raise ValueError("PNG encoding failed")
            out.append(buf.tobytes())
        return out
    raise ValueError(f"frames cannot be stored with encoding {encoding!r}")


def decode_frames(blobs: list[bytes], encoding: Encoding, shape: tuple[int, ...]) -> np.ndarray:
    """Inverse of :func:`encode_frames`: ``(T, *shape) uint8``."""
    out = np.empty((len(blobs), *shape), np.uint8)
    for i, b in enumerate(blobs):
        if encoding == "raw":
            out[i] = np.frombuffer(b, np.uint8).reshape(shape)
        elif encoding == "png":
            img = cv2.imdecode(np.frombuffer(b, np.uint8), cv2.IMREAD_COLOR)
            if img is None or img.shape != tuple(shape):
                raise ValueError(f"frame {i} is not a {shape} PNG")
            out[i] = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
        else:
            raise ValueError(f"frames cannot be decoded with encoding {encoding!r}")
    return out
