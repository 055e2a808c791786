"""Decoded frames on disk: a ``.npy`` file of ``(N, H, W, 3) uint8`` read a few rows at a time.

Training draws a batch's rows from every episode at random, so the frames of a dataset
larger than memory cannot come from its Parquet files (PNG-encoded, one file per episode)
without decoding whole episodes per batch. :func:`write_frame_file` writes the decoded
frames once into one plain ``.npy`` file (``np.load`` reads it too), atomically;
:class:`FrameFile` then serves ``frames[rows]`` with one ``pread`` per run of consecutive
rows. The data goes through the OS page cache, which every process reading the file shares
(the trials of a study), and never counts towards a process's resident memory: a memory map
would (its touched pages are part of RSS until the kernel reclaims them).

Beside the file, :func:`write_frame_file` writes its SHA-256 (``<name>.sha256``, as
``sha256sum`` writes it), which :meth:`FrameFile.verify` checks: zeroed or altered frames in
the file are found before training uses them.

No pyarrow here: :mod:`safe_bc.data.store` decodes the episodes and keys the file by the
dataset's content.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from safe_bc.data.atomic import atomic_write, write_text_atomic


class FrameFileError(ValueError):
    """A frame file is missing, truncated or not the array it should be (one line)."""


def _header_bytes(shape: tuple[int, ...]) -> bytes:
    """The ``.npy`` (version 1.0) header of a C-order ``uint8`` array of ``shape``."""
    import io

    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        buf, {"descr": "|u1", "fortran_order": False, "shape": tuple(int(s) for s in shape)}
    )
    return buf.getvalue()


def checksum_path(path: Path) -> Path:
    """Where the SHA-256 of the frame file ``path`` is kept: ``<name without .npy>.sha256``."""
    return Path(path).with_suffix(".sha256")


def write_frame_file(path: Path, shape: tuple[int, ...], chunks: Iterable[np.ndarray]) -> Path:
    """Write the ``uint8`` frames of ``chunks`` (each ``(T_i, *shape[1:])``, in order, summing
    to ``shape[0]`` rows) to ``path`` as one ``.npy`` array, atomically: a reader sees no file
    or the whole one. Holds one chunk at a time. Then writes the file's SHA-256 to
    :func:`checksum_path` (atomically too: a file without it is not verified, see
    :meth:`FrameFile.verify`)."""
    path = Path(path)
    rows = 0
    digest = hashlib.sha256()
    with atomic_write(path) as f:
        header = _header_bytes(shape)
        f.write(header)
        digest.update(header)
        for chunk in chunks:
            chunk = np.ascontiguousarray(chunk)
            if chunk.dtype != np.uint8 or chunk.shape[1:] != tuple(shape[1:]):
                raise ValueError(
                    f"frames must be (T, {', '.join(map(str, shape[1:]))}) uint8, "
                    f"got {chunk.shape} {chunk.dtype}"
                )
            f.write(chunk.data)
            digest.update(chunk.data)
            rows += len(chunk)
        if rows != shape[0]:
            raise ValueError(f"{rows} frames written, the header says {shape[0]}")
    write_text_atomic(checksum_path(path), f"{digest.hexdigest()}  {path.name}\n")
    return path


def frame_rows(key: Any, n: int, what: str = "rows") -> tuple[np.ndarray, bool]:
    """The rows a frame sequence of ``n`` frames is indexed with (an int, a slice, a boolean
    mask or a 1-d integer index; negative rows count from the end) as non-negative int64 rows,
    and whether ``key`` asked for one frame (an int).

    >>> frame_rows(-1, 4), frame_rows(slice(1, 3), 4)[0].tolist()
    ((array([3]), True), [1, 2])
    """
    if isinstance(key, (int, np.integer)):
        return frame_rows(np.asarray([key]), n, what)[0], True
    if isinstance(key, slice):
        return np.arange(n)[key].astype(np.int64), False
    rows = np.asarray(key)
    if rows.dtype == bool:
        rows = np.flatnonzero(rows)
    if rows.ndim != 1 or rows.dtype.kind not in "iu":
        raise IndexError(f"{what} must be an int, a slice or a 1-d index, got {key!r}")
    rows = rows.astype(np.int64)
    if rows.size and (rows.min() < -n or rows.max() >= n):
        raise IndexError(f"row out of range for {n} frames")
    return np.where(rows < 0, rows + n, rows), False


class FrameFile:
    """``(N, *frame) uint8`` frames in a ``.npy`` file, indexed like an array.

    ``frames[rows]`` (an int, a slice or an integer array) reads just those rows, in the
    order asked, into a fresh C-contiguous array: the same values and layout as indexing the
    in-memory array. Opening checks the header against ``shape`` and the file's size against
    the header (a truncated file is a :class:`FrameFileError`). Pickles by path (a Ray task
    reopens it). ``np.asarray(frames)`` reads every row (for code that needs the array).
    """

    def __init__(self, path: Path, shape: tuple[int, ...]) -> None:
        self.path = Path(path)
        self.shape = tuple(int(s) for s in shape)
        self.dtype = np.dtype(np.uint8)
        self._row_bytes = int(np.prod(self.shape[1:], dtype=np.int64))
        self._offset = self._check()
        self._fd: int | None = None

    def _check(self) -> int:
        """The data's offset in the file, after checking header and size."""
        try:
            with open(self.path, "rb") as f:
                if np.lib.format.read_magic(f) != (1, 0):
                    raise ValueError("not a version 1.0 .npy header")
                shape, fortran, dtype = np.lib.format.read_array_header_1_0(f)
                offset = f.tell()
                size = os.fstat(f.fileno()).st_size
        except OSError as e:
            raise FrameFileError(f"{self.path}: cannot read the frame file ({e})") from None
        except ValueError as e:
            raise FrameFileError(f"{self.path}: not a .npy frame file ({e})") from None
        if tuple(shape) != self.shape or dtype != self.dtype or fortran:
            raise FrameFileError(
                f"{self.path}: holds {dtype} {tuple(shape)}, expected uint8 {self.shape}"
            )
        expected = offset + self.shape[0] * self._row_bytes
        if size != expected:
            raise FrameFileError(
                f"{self.path}: {size} bytes, expected {expected} (truncated or overwritten)"
            )
        return offset

    def verify(self) -> None:
        """Check the file against the SHA-256 :func:`write_frame_file` wrote beside it (reads
        the whole file once): a :class:`FrameFileError` when it differs (frames zeroed or
        altered) or when there is no checksum to check against."""
        sidecar = checksum_path(self.path)
        try:
            recorded = sidecar.read_text().split()[0]
        except (OSError, IndexError, UnicodeDecodeError):
            raise FrameFileError(
                f"{self.path}: no checksum to verify it by ({sidecar.name})"
            ) from None
        digest = hashlib.sha256()
        try:
            with open(self.path, "rb") as f:
                while piece := f.read(2**20):
                    digest.update(piece)
        except OSError as e:
            raise FrameFileError(f"{self.path}: cannot read the frame file ({e})") from None
        if digest.hexdigest() != recorded:
            raise FrameFileError(
                f"{self.path}: its frames do not match the checksum written with it (damaged)"
            )

    @property
    def ndim(self) -> int:
        return len(self.shape)

    @property
    def nbytes(self) -> int:
        return self.shape[0] * self._row_bytes

    def __len__(self) -> int:
        return self.shape[0]

    def __repr__(self) -> str:
        return f"FrameFile({str(self.path)!r}, shape={self.shape})"

    def __getstate__(self) -> dict[str, Any]:
        return {"path": self.path, "shape": self.shape}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(state["path"], state["shape"])  # type: ignore[misc]

    def __del__(self) -> None:
        self.close()

    def close(self) -> None:
        """Close the file descriptor (reopened on the next read)."""
        fd, self._fd = getattr(self, "_fd", None), None
        if fd is not None:
            os.close(fd)

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        out = self[np.arange(len(self))]
        return out if dtype is None else out.astype(dtype, copy=False)

    def __getitem__(self, key: Any) -> np.ndarray:
        rows, one = frame_rows(key, len(self), "FrameFile rows")
        out = np.empty((len(rows), *self.shape[1:]), np.uint8)
        self._read_into(rows, out)
        return out[0] if one else out

    def _read_into(self, rows: np.ndarray, out: np.ndarray) -> None:
        """Fill ``out[i] = frame rows[i]``: one ``pread`` per run of consecutive rows."""
        if not rows.size:
            return
        if self._fd is None:
            self._fd = os.open(self.path, os.O_RDONLY)
        unique = np.unique(rows)
        breaks = np.flatnonzero(np.diff(unique) != 1) + 1
        flat = np.empty((len(unique), self._row_bytes), np.uint8)
        for lo, hi in zip(np.r_[0, breaks], np.r_[breaks, len(unique)], strict=True):
            view = memoryview(flat[lo:hi]).cast("B")
            at = self._offset + int(unique[lo]) * self._row_bytes
            got = os.preadv(self._fd, [view], at)
            while got < len(view):  # preadv may return short reads
                more = os.preadv(self._fd, [view[got:]], at + got)
                if more == 0:
                    raise FrameFileError(f"{self.path}: ended early (truncated while open?)")
                got += more
        np.take(flat, np.searchsorted(unique, rows), axis=0, out=out.reshape(len(rows), -1))
