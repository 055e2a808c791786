"""Round files (``kept.npz``, written atomically: the round's track outcomes and kept pieces;
numpy only, no torch). The training data (demonstrations plus the kept pieces' rows) is
:func:`safe_bc.methods.rounds.aggregate_rows`'s."""

from __future__ import annotations

import zipfile
from collections.abc import Iterator, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from safe_bc.data.atomic import atomic_write
from safe_bc.methods.selfimprove.rollout import KeptPiece, TrackResult

_ROW_FIELDS = ("steps", "trained", "observations", "actions", "costs")


def save_round(path: Path, tracks: Sequence[TrackResult], frames: bool = True) -> None:
    """One round's track results to ``path`` (``.npz``, deflated at
    :data:`ROUND_COMPRESSLEVEL`: a CarRacing round keeps ~80k frames, ~2 GB raw), atomically:
    a killed write leaves none. ``frames=False``: the pieces' observations are left out (the
    run's :class:`~safe_bc.methods.selfimprove.store.KeptFrameStore` holds them, in
    :func:`round_frames`' order) and the file says so (:func:`holds_frames`)."""
    if not frames:
        tracks = [replace(t, pieces=tuple(frameless(p) for p in t.pieces)) for t in tracks]
    pieces = [p for t in tracks for p in t.pieces]
    arrays: dict[str, np.ndarray] = {
        "seed": np.asarray([t.seed for t in tracks], np.int64),
        "reference_reward": np.asarray([t.reference_reward for t in tracks], np.float64),
        "reference_beyond": np.asarray([t.reference_beyond for t in tracks], np.int64),
        "push_rewards": np.asarray([t.push_rewards for t in tracks], np.float64),
        "push_beyond": np.asarray([t.push_beyond for t in tracks], np.int64),
        "push_kept": np.asarray([t.push_kept for t in tracks], np.int64),
        "reference_steps": np.asarray([t.reference_steps for t in tracks], np.int64),
        "push_steps": np.asarray([t.push_steps for t in tracks], np.int64),
        "expert_reward": np.asarray([t.expert_reward for t in tracks], np.float64),
        "expert_steps": np.asarray([t.expert_steps for t in tracks], np.int64),
        "push_deferred": np.asarray(
            [t.push_deferred for t in tracks] if tracks else np.empty((0, 0)), np.int64
        ),
        "piece_track": np.asarray([i for i, t in enumerate(tracks) for _ in t.pieces], np.int64),
        "piece_push": np.asarray([p.push for p in pieces], np.int64),
        "piece_rows": np.asarray([len(p.steps) for p in pieces], np.int64),
    }
    if not frames:
        arrays[FRAMES_ELSEWHERE] = np.asarray(True)
    for name in _ROW_FIELDS:
        parts = [getattr(p, name) for p in pieces]
        arrays[name] = np.concatenate(parts) if parts else np.empty((0,), np.float32)
    with atomic_write(path) as f:
        _savez_fast(f, arrays)


FRAMES_ELSEWHERE = "frames_in_store"
"""Array name marking a round file whose pieces' frames are in the run's kept-frame store."""


def holds_frames(path: Path) -> bool:
    """The round file ``path`` holds its pieces' frames (written before the kept-frame store,
    or by a run whose frames stay in memory)."""
    with zipfile.ZipFile(path) as z:
        return f"{FRAMES_ELSEWHERE}.npy" not in z.namelist()


def round_frames(tracks: Sequence[TrackResult]) -> Iterator[np.ndarray]:
    """The frames of a round's pieces with rows, in the order training aggregates them."""
    return (p.observations for t in tracks for p in t.pieces if len(p.steps))


ROUND_COMPRESSLEVEL = 1
"""zlib level of a round file's arrays. On 3,000 CarRacing frames (83 MB) level 1 wrote in
0.21 CPU s against ``np.savez_compressed``'s 0.64 s (zlib's default 6), 5.0 MB against 3.2 MB,
read back in 0.16 s against 0.10 s: a round writes ~80k frames once and reads them at
every later retraining, so the faster write wins (the same arrays either way; ``np.load``
reads both)."""


def _savez_fast(f: Any, arrays: dict[str, np.ndarray]) -> None:
    """``arrays`` as an ``.npz`` (one ``.npy`` member each) deflated at
    :data:`ROUND_COMPRESSLEVEL`."""
    with zipfile.ZipFile(f, "w", zipfile.ZIP_DEFLATED, compresslevel=ROUND_COMPRESSLEVEL) as z:
        for name, value in arrays.items():
            with z.open(f"{name}.npy", "w", force_zip64=True) as member:
                np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=False)


def load_round(path: Path, frames: bool = True) -> list[TrackResult]:
    """The track results :func:`save_round` wrote; with ``frames=False`` the pieces'
    observations are ``(R, 0)`` placeholders and the file's frames are never decompressed (a
    CarRacing round's are ~2 GB: :func:`frame_chunks` streams them one round at a time)."""
    with np.load(path) as z:
        a = {k: z[k] for k in z.files if frames or k != "observations"}
    if not frames or FRAMES_ELSEWHERE in a:
        a["observations"] = np.empty((int(a["piece_rows"].sum()), 0), np.uint8)
    bounds = np.r_[0, np.cumsum(a["piece_rows"])]
    pieces: list[list[KeptPiece]] = [[] for _ in a["seed"]]
    for j, track in enumerate(a["piece_track"]):
        rows = slice(int(bounds[j]), int(bounds[j + 1]))
        pieces[int(track)].append(
            KeptPiece(
                seed=int(a["seed"][track]),
                push=int(a["piece_push"][j]),
                steps=a["steps"][rows].astype(np.int64),
                trained=a["trained"][rows].astype(bool),
                observations=a["observations"][rows],
                actions=a["actions"][rows],
                costs=a["costs"][rows],
            )
        )
    return [
        TrackResult(
            seed=int(a["seed"][i]),
            reference_reward=float(a["reference_reward"][i]),
            reference_beyond=int(a["reference_beyond"][i]),
            push_rewards=tuple(float(x) for x in a["push_rewards"][i]),
            push_beyond=tuple(int(x) for x in a["push_beyond"][i]),
            push_kept=tuple(int(x) for x in a["push_kept"][i]),
            reference_steps=int(a["reference_steps"][i]),
            push_steps=tuple(int(x) for x in a["push_steps"][i]),
            pieces=tuple(pieces[i]),
            expert_reward=float(a["expert_reward"][i]) if "expert_reward" in a else float("nan"),
            push_deferred=tuple(int(x) for x in a["push_deferred"][i])
            if "push_deferred" in a
            else (),
            expert_steps=int(a["expert_steps"][i]) if "expert_steps" in a else 0,
        )
        for i in range(len(a["seed"]))
    ]


def frameless(piece: KeptPiece) -> KeptPiece:
    """``piece`` with a ``(R, 0)`` placeholder for its frames (they stay in its round file)."""
    return replace(piece, observations=np.empty((len(piece.steps), 0), np.uint8))


def frame_chunks(
    demos_frames: Any, kept_files: Sequence[Path], pieces: Sequence[KeptPiece], block: int = 4096
) -> Iterator[np.ndarray]:
    """The frames of the demonstrations (``block`` rows at a time), then of the pieces with
    rows in each of ``kept_files`` (one file decompressed at a time), then of ``pieces``: the
    row order of :func:`safe_bc.methods.rounds.aggregate_rows` over those pieces, for
    :func:`safe_bc.data.frames.write_frame_file`. (How each retraining's frame file was
    built before the kept-frame store; ``benchmarks/cases/selfimprove.py`` times it.)"""
    for i in range(0, len(demos_frames), block):
        yield np.asarray(demos_frames[i : i + block])
    for f in kept_files:
        yield from round_frames(load_round(f))
    yield from (p.observations for p in pieces if len(p.steps))
