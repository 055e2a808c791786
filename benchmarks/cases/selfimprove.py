"""The ``selfimprove`` case of ``python -m benchmarks.bench``."""

from __future__ import annotations

import hashlib
import shutil
import tempfile
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.bench import (
    Sizes,
    _order,
    _row,
    _self_row,
)
from benchmarks.cases.eval import untrained_source

SELFIMPROVE_ENVS = 8
"""The lockstep width the ``selfimprove`` case times (``SelfImproveConfig.lockstep_envs``)."""


def _car_frames(n: int, seed: int) -> np.ndarray:
    """``n`` CarRacing frames of a random driver (real frames: they compress as kept ones do)."""
    from safe_bc.tasks import make_env, task_defaults

    env = make_env(task_defaults("carracing").env)
    rng = np.random.default_rng(seed)
    frames, (obs, _) = [], env.reset(seed=seed)
    while len(frames) < n:
        frames.append(obs)
        action = np.array([rng.uniform(-1, 1), rng.uniform(0, 0.5), 0.0], np.float32)
        obs, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            obs, _ = env.reset(seed=seed + len(frames))
    env.close()
    return np.stack(frames).astype(np.uint8)


def _kept_round(frames: np.ndarray, r: int) -> list[Any]:
    """One track whose one kept piece holds ``frames``."""
    from safe_bc.methods.selfimprove.rollout import KeptPiece, TrackResult

    k = len(frames)
    piece = KeptPiece(
        seed=r, push=0, steps=np.arange(k, dtype=np.int64), trained=np.ones(k, bool),
        observations=frames, actions=np.zeros((k, 3), np.float32),
        costs=np.zeros((k, 3), np.float32),
    )  # fmt: skip
    return [TrackResult(r, 0.0, 0, (0.0,), (0,), (k,), k, (k,), (piece,))]


def kept_frames_old(folder: Path, demos: Any, rounds: list[list[Any]]) -> Any:
    """The kept frames' path before the store, every round accepted: the round file deflated
    with its frames, then the retraining's frame file rebuilt from the demonstrations and
    every accepted round file (decompressed), deleted after. The last round's frames."""
    from safe_bc.data.frames import FrameFile, checksum_path, write_frame_file
    from safe_bc.methods.selfimprove.data import frame_chunks, save_round

    files: list[Path] = []
    frame = tuple(demos.shape[1:])
    for r, tracks in enumerate(rounds):
        save_round(folder / f"kept{r}.npz", tracks)
        mine = [p for t in tracks for p in t.pieces]
        n = len(demos) + sum(len(p.steps) for t in rounds[: r + 1] for p in t[0].pieces)
        path = write_frame_file(
            folder / "frames.npy", (n, *frame), frame_chunks(demos, files, mine)
        )
        last = FrameFile(path, (n, *frame))
        if r < len(rounds) - 1:
            last.close()
            path.unlink()
            checksum_path(path).unlink()
        files.append(folder / f"kept{r}.npz")
    return last


def kept_frames_new(folder: Path, demos: Any, rounds: list[list[Any]]) -> Any:
    """The kept-frame store, every round accepted: the frames appended raw, the round file
    without them, the retraining's frames read through the demonstrations' and the store's
    files. The last round's frames."""
    from safe_bc.methods.selfimprove.data import round_frames, save_round
    from safe_bc.methods.selfimprove.store import ConcatFrames, KeptFrameStore

    store = KeptFrameStore(folder, tuple(demos.shape[1:]))
    for r, tracks in enumerate(rounds):
        store.append(r, round_frames(tracks))
        save_round(folder / f"kept{r}.npz", tracks, frames=False)
        last = ConcatFrames([demos, store.frames()])
        if r < len(rounds) - 1:
            last.close()
        store.settle(r, True)
    return last


def bench_selfimprove(sizes: Sizes, repeats: int, seed: int) -> dict[str, Any]:
    """CPU seconds of a self-imitation round, old against new side by side in one process.

    Rollouts (training runs, then as many validation episodes as tracks): one env at a time
    (the path before lockstep rollouts) against :data:`SELFIMPROVE_ENVS` envs in lockstep with
    one-row forward passes (the same runs bit for bit) and with one batched forward pass.
    Kept frames (``sizes.selfimprove_rounds`` accepted rounds of ``sizes.selfimprove_kept``
    real car frames each, as many demonstration frames in a frame file): round files with
    their frames and a frame file rebuilt for each retraining (:func:`kept_frames_old`)
    against the append-only store (:func:`kept_frames_new`); the last retraining's frames are
    checked equal. A round: the rollouts plus a round's share of the kept frames. CPU time
    (``time.process_time``, one torch thread), so a loaded machine moves it less."""
    import torch

    from safe_bc.data.frames import FrameFile, write_frame_file
    from safe_bc.methods.selfimprove.config import LOOP_PUSHES
    from safe_bc.methods.selfimprove.rollout import ExploreJob, ValidateJob, explore_track
    from safe_bc.tasks import make_env, task_defaults

    torch.set_num_threads(1)
    spec = task_defaults("carracing")
    source = untrained_source(seed)
    limits = (42.0, 51.0, 42.0)
    bounds = tuple(np.asarray(b, np.float32) for b in spec.action_bounds)
    base = ExploreJob(
        spec.env, source, LOOP_PUSHES["carracing"], bounds, limits, backoff_eps=2.0,
        max_steps=sizes.selfimprove_steps, rng_seed=seed,
    )  # fmt: skip
    val = ValidateJob(spec.env, source, limits, 2.0, max_steps=sizes.selfimprove_steps)
    seeds = [seed + i for i in range(sizes.selfimprove_tracks)]
    n = SELFIMPROVE_ENVS

    def one_env() -> None:
        env = make_env(spec.env)
        agent = source.build()
        [explore_track(env, agent, base, s) for s in seeds]
        env.close()
        val.run(seeds)

    variants: dict[str, Callable[[], Any]] = {
        "one env at a time": one_env,
        f"{n} envs lockstep, one-row forwards": lambda: (
            replace(base, lockstep_envs=n).run(seeds),
            replace(val, lockstep_envs=n).run(seeds),
        ),
        f"{n} envs lockstep, batched forward": lambda: (
            replace(base, lockstep_envs=n, forward="batched").run(seeds),
            replace(val, lockstep_envs=n, forward="batched").run(seeds),
        ),
    }
    frames = _car_frames(sizes.selfimprove_kept, seed)
    rounds = [_kept_round(frames, r) for r in range(sizes.selfimprove_rounds)]
    scratch = Path(tempfile.mkdtemp(prefix="bench_selfimprove_"))
    shape = (len(frames), *frames.shape[1:])
    demos = FrameFile(write_frame_file(scratch / "demos.npy", shape, [frames]), shape)
    data: dict[str, Callable[[Path], Any]] = {
        "kept frames: round files with frames, frame file rebuilt": lambda d: kept_frames_old(
            d, demos, rounds
        ),
        "kept frames: append-only store": lambda d: kept_frames_new(d, demos, rounds),
    }
    timed = [*variants, *data]
    cpu: dict[str, list[float]] = {name: [] for name in timed}
    try:
        for rep in range(repeats):
            for name in _order(timed, rep):
                here = scratch / f"{rep}-{timed.index(name)}"
                here.mkdir()
                t0 = time.process_time()
                got = data[name](here) if name in data else variants[name]()
                cpu[name].append(time.process_time() - t0)
                if name in data:
                    last = np.asarray(got)
                    got.close()
                    if rep == 0:  # both paths give the last retraining the same frames
                        expected = np.concatenate([frames] * (1 + len(rounds)))
                        assert np.array_equal(last, expected), name
                    del last
                shutil.rmtree(here)
    finally:
        demos.close()
        shutil.rmtree(scratch, ignore_errors=True)
    runs = len(seeds) * (1 + len(base.pushes)) + len(seeds)
    note = (
        f"{len(seeds)} CarRacing tracks x (1 + {len(base.pushes)} pushes) runs and "
        f"{len(seeds)} validation episodes of at most {sizes.selfimprove_steps} steps "
        f"({runs} episodes), an untrained default BC net, one torch thread; CPU seconds "
        "(env builds included); ratio: CPU time against one env at a time (lower is faster)"
    )
    old_data, new_data = list(data)
    share = 1 / len(rounds)
    per_round = {
        "a round: one env, round files with frames (the path before)": (
            "one env at a time", old_data),
        f"a round: {n} envs lockstep one-row forwards, store (the default; bit-identical)": (
            f"{n} envs lockstep, one-row forwards", new_data),
        f"a round: {n} envs lockstep batched forward, store": (
            f"{n} envs lockstep, batched forward", new_data),
    }  # fmt: skip
    for name, (roll, kept) in per_round.items():
        cpu[name] = [a + share * b for a, b in zip(cpu[roll], cpu[kept], strict=True)]
    data_note = (
        f"{len(rounds)} accepted rounds of {len(frames)} kept CarRacing frames each and as "
        f"many demonstration frames in a frame file; ratio: CPU time against the round files "
        "with frames (lower is faster)"
    )
    round_note = (
        f"the rollouts above plus 1/{len(rounds)} of the kept-frame variant below; ratio: "
        "against one env and round files with frames (lower is faster)"
    )
    first, *rest = list(variants)
    base_round, *new_rounds = list(per_round)
    inputs = {
        "kept_frames_sha256": hashlib.sha256(frames.tobytes()).hexdigest(),
        "kept_frames_shape": list(frames.shape),
        "tracks": [int(s) for s in seeds],
        "seed": seed,
    }
    return {
        "inputs": inputs,
        "rows": [
            _self_row("selfimprove", first, cpu[first], "CPU s", note),
            *(
                _row("selfimprove", v, cpu[v], "CPU s", (first, cpu[first]), note, paired=True)
                for v in rest
            ),
            _self_row("selfimprove", old_data, cpu[old_data], "CPU s", data_note),
            _row(
                "selfimprove",
                new_data,
                cpu[new_data],
                "CPU s",
                (old_data, cpu[old_data]),
                data_note,
                paired=True,
            ),
            _self_row("selfimprove", base_round, cpu[base_round], "CPU s", round_note),
            *(
                _row(
                    "selfimprove",
                    v,
                    cpu[v],
                    "CPU s",
                    (base_round, cpu[base_round]),
                    round_note,
                    paired=True,
                )
                for v in new_rounds
            ),
        ],
    }
