"""The ``stream`` case of ``python -m benchmarks.bench``."""

from __future__ import annotations

import contextlib
import resource
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.bench import (
    PAIRED_NOTE,
    Sizes,
    _maxrss_mb,
    _order,
    _row,
    _self_row,
)
from benchmarks.cases.train import BATCH_SIZE, run_config


def dataset_read(sizes: Sizes) -> dict[str, Any] | None:
    """The record (path, digest, episodes) of the source set this case reads at these sizes;
    ``None`` when it makes synthetic episodes instead (the harness's ``bench_inputs``)."""
    source = Path(sizes.stream_source) if sizes.stream_source else None
    if source is None or not source.is_dir():
        return None
    from safe_bc.data.store import dataset_record

    return dataset_record(source)


def _synthetic_store(root: Path, episodes: int, steps: int, seed: int) -> Path:
    """``episodes`` CarRacing-shaped episodes of ``steps`` random frames, PNG-encoded."""
    from safe_bc.data.episode import SAFETY_DIMS, Episode
    from safe_bc.data.store import DatasetMeta, init_dataset, write_episode

    meta = init_dataset(
        root,
        DatasetMeta(
            env_id="CarRacing-v3",
            obs_encoding="png",
            obs_shape=(96, 96, 3),
            safety_dims=SAFETY_DIMS,
            seed=seed,
            max_steps=steps,
            expert={"type": "synthetic"},
            perturbation={"mode": "none"},
        ),
    )
    rng = np.random.default_rng(seed)
    for i in range(episodes):
        costs = rng.uniform(0, 40, (steps, 3)).astype(np.float32)
        actions = rng.uniform(0, 1, (steps, 3)).astype(np.float32)
        ep = Episode(
            episode_id=i,
            seed=seed + i,
            observations=rng.integers(0, 256, (steps, 96, 96, 3), dtype=np.uint8),
            actions=actions,
            executed_actions=actions,
            rewards=np.zeros(steps, np.float32),
            terminated=np.arange(steps) == steps - 1,
            truncated=np.zeros(steps, bool),
            safety=40 - costs,
            costs=costs,
            warmup=np.zeros(steps, bool),
            offroad=np.zeros(steps, bool),
        )
        write_episode(root, ep, meta)
    return root


def _recoded_store(source: Path, root: Path, episodes: int) -> Path:
    """``episodes`` episodes at ``root``: the source's, in turn, each written again under a
    new episode id and env seed (a larger dataset of real frames without collecting)."""
    from safe_bc.data.store import init_dataset, read_episodes, read_meta, write_episode

    meta = init_dataset(root, read_meta(source))
    eps = read_episodes(source)
    offset = max(ep.seed for ep in eps) + 1
    for i in range(episodes):
        ep = eps[i % len(eps)]
        write_episode(
            root, replace(ep, episode_id=i, seed=ep.seed + offset * (i // len(eps))), meta
        )
    return root


def _peak_rss_mb() -> float:
    """This process's RSS high-water mark (``VmHWM``), MiB: unlike ``ru_maxrss`` it starts
    afresh at ``exec``, so a spawned child does not inherit its parent's."""
    with contextlib.suppress(OSError):
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    return _maxrss_mb(resource.RUSAGE_SELF)


def _stream_run(root: str, frames: str, batches: int, seed: int, conn: Any) -> None:
    """In a spawned process: load the dataset at ``root`` with ``frames`` and train; sends
    ``{peak_mb, load_s, samples_per_s, weights}`` (a digest of the weights) on ``conn``."""
    import hashlib

    from safe_bc.data.store import load_demonstrations
    from safe_bc.methods.experiment import train_run

    start = time.perf_counter()
    demos = load_demonstrations(Path(root), frames)  # type: ignore[arg-type]
    load_s = time.perf_counter() - start
    result = train_run(demos, run_config(batches, seed))[0]
    digest = hashlib.sha256()
    for value in result.model.state_dict().values():
        digest.update(value.numpy().tobytes())
    conn.send(
        {
            "peak_mb": _peak_rss_mb(),
            "load_s": load_s,
            "samples_per_s": result.samples_per_s,
            "weights": digest.hexdigest(),
        }
    )
    conn.close()


def _spawned(root: Path, frames: str, batches: int, seed: int) -> dict[str, Any]:
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    receive, send = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_stream_run, args=(str(root), frames, batches, seed, send))
    proc.start()
    send.close()
    try:
        out = receive.recv()
    except EOFError:
        out = None  # it died before sending
    proc.join()
    if out is None or proc.exitcode != 0:
        raise RuntimeError(f"stream run ({frames}, {root}) exited with {proc.exitcode}")
    return out


def bench_stream(sizes: Sizes, repeats: int, seed: int) -> list[dict[str, Any]]:
    """Peak RSS of loading a dataset and ``train_bc`` on it, frames in memory vs streamed from
    the dataset's decoded-frame file, for growing datasets; each run in a fresh process."""
    from safe_bc.data.store import load_demonstrations

    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="bench-stream-") as tmp:
        source = Path(sizes.stream_source) if sizes.stream_source else None
        if source is None or not (source / "dataset.json").exists():
            source = _synthetic_store(Path(tmp) / "source", 5, sizes.stream_synthetic_steps, seed)
        for episodes in sizes.stream_episodes:
            root = _recoded_store(source, Path(tmp) / f"e{episodes}", episodes)
            start = time.perf_counter()
            n = len(load_demonstrations(root, "stream"))  # writes the frame file, once
            build_s = time.perf_counter() - start
            runs: dict[str, list[dict[str, Any]]] = {"memory": [], "stream": []}
            for rep in range(repeats):
                for frames in _order(list(runs), rep):
                    runs[frames].append(_spawned(root, frames, sizes.stream_batches, seed))
            same = {r["weights"] for rs in runs.values() for r in rs}
            work = (
                f"{episodes} episodes ({n} pairs), {sizes.stream_batches} batches x {BATCH_SIZE}, "
                f"default configs, each run in a fresh process; weights identical across modes: "
                f"{'yes' if len(same) == 1 else 'NO'}"
            )

            def values(frames: str, key: str, r: dict[str, list[dict[str, Any]]] = runs):
                return [run[key] for run in r[frames]]

            label = f"{episodes} episodes"
            mem, stream = f"{label}, memory", f"{label}, stream"
            rows += [
                _self_row("stream", f"{mem}: peak RSS", values("memory", "peak_mb"), "MiB", work),
                _row(
                    "stream",
                    f"{stream}: peak RSS",
                    values("stream", "peak_mb"),
                    "MiB",
                    (f"{mem}: peak RSS", values("memory", "peak_mb")),
                    f"{work}; VmHWM of the run's process (load + train)",
                ),
                _self_row(
                    "stream", f"{mem}: train_bc", values("memory", "samples_per_s"), "samples/s"
                ),
                _row(
                    "stream",
                    f"{stream}: train_bc",
                    values("stream", "samples_per_s"),
                    "samples/s",
                    (f"{mem}: train_bc", values("memory", "samples_per_s")),
                    f"training loop only; {PAIRED_NOTE}",
                    paired=True,
                ),
                _self_row("stream", f"{mem}: load", values("memory", "load_s"), "s"),
                _row(
                    "stream",
                    f"{stream}: load",
                    values("stream", "load_s"),
                    "s",
                    (f"{mem}: load", values("memory", "load_s")),
                    f"frame file present; writing it (decoding every episode once) took "
                    f"{build_s:.1f} s; {PAIRED_NOTE}",
                    paired=True,
                ),
            ]
    return rows
