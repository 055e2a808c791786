"""A run's kept frames in one append-only file (numpy only, no torch).

Each round's kept frames (``uint8``, the rows of its pieces with data, in the order of its
round file) are appended raw to ``kept_frames.bin`` in the run folder, and
``kept_frames.json`` records the row range of every round there: accepted, or pending while
the round trains and validates. A retraining reads the demonstrations' frames and the rows of
the accepted rounds plus its own through :class:`ConcatFrames` (one ``pread`` per run of
consecutive rows, as :class:`~safe_bc.data.frames.FrameFile`): the rows of one frame file
rebuilt from every kept round, without rewriting or decompressing them.

A rejected round's rows are cut off the file's end (:meth:`KeptFrameStore.settle`); on
resume :meth:`KeptFrameStore.reconcile` keeps the accepted done rounds' rows and the pending
rows of the round about to rerun (when its round file was written), and cuts the rest: rows
appended by a round killed before it was settled never reach a later round's training.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from safe_bc.data.atomic import write_json_atomic
from safe_bc.data.frames import FrameFile, FrameFileError, frame_rows

STORE = "kept_frames.bin"
"""The run's kept frames, raw ``uint8`` rows, no header (:data:`STORE_INDEX` says the shape)."""
STORE_INDEX = "kept_frames.json"
"""The row range of each round in :data:`STORE`."""
STORE_FORMAT = "safe_bc.selfimprove.kept_frames/1"


class RawFrames(FrameFile):
    """The first ``shape[0]`` rows of a headerless ``uint8`` file of ``shape[1:]`` rows (the file
    may hold more: rows appended later). Reads like :class:`FrameFile`."""

    def _check(self) -> int:
        try:
            size = os.stat(self.path).st_size
        except OSError as e:
            raise FrameFileError(f"{self.path}: cannot read the frame file ({e})") from None
        if size < self.nbytes:
            raise FrameFileError(
                f"{self.path}: {size} bytes, {self.shape[0]} rows need {self.nbytes} (truncated)"
            )
        return 0

    def __repr__(self) -> str:
        return f"RawFrames({str(self.path)!r}, shape={self.shape})"


class ConcatFrames:
    """Arrays (or :class:`FrameFile` s) of the same frame shape, one after another, indexed like
    their concatenation: ``frames[rows]`` reads each part's rows once, in the order asked."""

    def __init__(self, parts: Sequence[Any]) -> None:
        self.parts = [p for p in parts if len(p)] or list(parts[:1])
        frame = {tuple(p.shape[1:]) for p in self.parts}
        if len(frame) != 1:
            raise ValueError(f"parts of different frame shapes: {sorted(frame)}")
        self.bounds = np.cumsum([0, *(len(p) for p in self.parts)])
        self.shape = (int(self.bounds[-1]), *frame.pop())
        self.dtype = np.dtype(self.parts[0].dtype)

    @property
    def ndim(self) -> int:
        return len(self.shape)

    def __len__(self) -> int:
        return self.shape[0]

    def __repr__(self) -> str:
        return f"ConcatFrames({self.parts!r})"

    def close(self) -> None:
        for p in self.parts:
            if hasattr(p, "close"):
                p.close()

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        out = self[np.arange(len(self))]
        return out if dtype is None else out.astype(dtype, copy=False)

    def __getitem__(self, key: Any) -> np.ndarray:
        rows, one = frame_rows(key, len(self))
        out = np.empty((len(rows), *self.shape[1:]), self.dtype)
        part = np.searchsorted(self.bounds, rows, side="right") - 1
        for i in np.unique(part):
            mine = np.flatnonzero(part == i)
            out[mine] = self.parts[i][rows[mine] - self.bounds[i]]
        return out[0] if one else out


class KeptFrameStore:
    """``kept_frames.bin`` and its index in a run folder (created empty when absent)."""

    def __init__(self, folder: Path, frame_shape: tuple[int, ...]) -> None:
        self.path = Path(folder) / STORE
        self.index_path = Path(folder) / STORE_INDEX
        self.frame_shape = tuple(int(s) for s in frame_shape)
        self.row_bytes = int(np.prod(self.frame_shape, dtype=np.int64))
        index = None
        if self.index_path.is_file():
            import json

            index = json.loads(self.index_path.read_text())
            if tuple(index["frame_shape"]) != self.frame_shape:
                raise ValueError(
                    f"{self.index_path}: frames {tuple(index['frame_shape'])}, the run's "
                    f"are {self.frame_shape}"
                )
        self.rounds: list[dict[str, Any]] = [] if index is None else list(index["rounds"])

    @property
    def rows(self) -> int:
        """Rows recorded (accepted and pending)."""
        return int(self.rounds[-1]["stop"]) if self.rounds else 0

    def _size(self) -> int:
        return self.path.stat().st_size if self.path.is_file() else 0

    def _write_index(self) -> None:
        write_json_atomic(
            self.index_path,
            {"format": STORE_FORMAT, "frame_shape": list(self.frame_shape), "rounds": self.rounds},
        )

    def _cut(self, rows: int) -> None:
        """Keep the first ``rows`` rows: the file cut there, later rounds out of the index."""
        self.rounds = [e for e in self.rounds if int(e["stop"]) <= rows]
        self._write_index()
        with open(self.path, "ab") as f:
            f.truncate(rows * self.row_bytes)

    def append(self, r: int, chunks: Iterable[np.ndarray]) -> tuple[int, int]:
        """Append round ``r``'s frames (``chunks`` of ``(T_i, *frame_shape) uint8``) as pending
        rows after the recorded ones (anything past them is cut first): ``(start, stop)``."""
        start = self.rows
        if self._size() != start * self.row_bytes:
            self._cut(start)
        stop = start
        with open(self.path, "ab") as f:
            for chunk in chunks:
                chunk = np.ascontiguousarray(chunk)
                if chunk.dtype != np.uint8 or chunk.shape[1:] != self.frame_shape:
                    raise ValueError(
                        f"frames must be (T, {', '.join(map(str, self.frame_shape))}) uint8, "
                        f"got {chunk.shape} {chunk.dtype}"
                    )
                f.write(chunk.data)
                stop += len(chunk)
            f.flush()
            os.fsync(f.fileno())
        self.rounds.append({"round": int(r), "start": start, "stop": stop, "accepted": None})
        self._write_index()
        return start, stop

    def settle(self, r: int, accepted: bool) -> None:
        """Round ``r`` (the last recorded) done: its rows accepted, or cut off when rejected."""
        last = self.rounds[-1] if self.rounds else None
        if last is None or int(last["round"]) != r:
            return  # settled already (or nothing appended)
        if accepted:
            last["accepted"] = True
            self._write_index()
        else:
            self.rounds.pop()  # (a round of no rows ends where it starts)
            self._cut(int(last["start"]))

    def reconcile(self, accepted: Sequence[tuple[int, int]], pending: int | None) -> list[int]:
        """Bring the store to the done rounds: ``accepted`` are the accepted done rounds in
        order, ``(round, rows)``; ``pending`` the round about to run when its round file was
        written (its recorded rows are kept when whole). Everything else recorded or written
        past them is cut. Returns the accepted rounds the store lacks (from the first one
        missing on: a run folder written before this store, whose round files hold their
        frames), to be appended by the caller in order."""
        pos, matched = 0, 0
        for (r, n), e in zip(accepted, self.rounds, strict=False):
            if (int(e["round"]), int(e["start"]), int(e["stop"])) != (r, pos, pos + n):
                break
            e["accepted"] = True
            pos, matched = pos + n, matched + 1
        size = self._size()
        if size < pos * self.row_bytes:  # the file lost accepted rows: re-append from there
            while matched and size < pos * self.row_bytes:
                matched -= 1
                pos -= accepted[matched][1]
        keep, kept = pos, matched
        if matched == len(accepted) and matched < len(self.rounds):
            e = self.rounds[matched]
            whole = size >= int(e["stop"]) * self.row_bytes
            if pending is not None and int(e["round"]) == pending and e["start"] == pos and whole:
                keep, kept, e["accepted"] = int(e["stop"]), matched + 1, None  # settled again
        self.rounds = self.rounds[:kept]
        self._cut(keep)
        return [r for r, _ in accepted[matched:]]

    def pending(self, r: int) -> bool:
        """Round ``r``'s rows are recorded, not yet settled."""
        return (
            bool(self.rounds)
            and int(self.rounds[-1]["round"]) == r
            and (self.rounds[-1]["accepted"] is None)
        )

    def frames(self, rows: int | None = None) -> RawFrames:
        """The first ``rows`` rows (all recorded ones) for reading."""
        rows = self.rows if rows is None else rows
        return RawFrames(self.path, (rows, *self.frame_shape))
