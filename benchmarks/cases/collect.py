"""The ``collect`` case of ``python -m benchmarks.bench``."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks.bench import (
    Sizes,
    _order,
    _row,
    _self_row,
)


def _collect_config(workers: int, sizes: Sizes, seed: int) -> Any:
    from safe_bc.rollout.collect import CollectConfig

    return CollectConfig(
        episodes=sizes.collect_episodes, workers=workers, seed=seed, max_steps=sizes.collect_steps
    )


def _collect_cold(workers: int, sizes: Sizes, seed: int) -> float:
    """``collect()`` into a fresh directory: ``CollectReport.steps_per_s`` (actor start-up,
    episode rollouts and the driver's Parquet writes)."""
    from safe_bc.distributed.collect import collect

    with tempfile.TemporaryDirectory(prefix="bench-collect-") as tmp:
        report = collect(_collect_config(workers, sizes, seed), Path(tmp) / "demos", progress=False)
    return report.steps_per_s


def _collect_warm(workers: int, sizes: Sizes, seed: int) -> tuple[float, float]:
    """``collect()``'s loop on actors that are already up: ``(steps/s, start-up seconds)``.

    Same actors, pool and driver-side Parquet writes as ``collect()``; the clock starts once
    every actor has finished its constructor (process start, imports, env and expert built).
    """
    import ray

    from safe_bc.data.store import init_dataset, write_episode
    from safe_bc.distributed.collect import RolloutWorker, dataset_meta
    from safe_bc.distributed.pool import run_on_actors
    from safe_bc.distributed.runtime import cpus_per_actor

    config = _collect_config(workers, sizes, seed)
    with tempfile.TemporaryDirectory(prefix="bench-collect-") as tmp:
        out = Path(tmp) / "demos"
        meta = init_dataset(out, dataset_meta(config))
        worker_cls = RolloutWorker.options(num_cpus=cpus_per_actor(workers), max_restarts=0)
        t0 = time.perf_counter()
        actors = [worker_cls.remote(config) for _ in range(workers)]
        ray.get([actor.__ray_ready__.remote() for actor in actors])
        startup = time.perf_counter() - t0
        handed_out = iter(actors)
        steps = 0

        def store(episode_id: int, episode: Any) -> None:
            nonlocal steps
            write_episode(out, episode, meta)
            steps += len(episode)

        t1 = time.perf_counter()
        run_on_actors(
            lambda: next(handed_out),
            workers,
            range(config.episodes),
            lambda actor, eid: actor.run_episode.remote(eid),
            store,
        )
        seconds = time.perf_counter() - t1
    return steps / seconds, startup


def bench_collect(sizes: Sizes, repeats: int, seed: int) -> list[dict[str, Any]]:
    """Collection steps/s with 1 vs 2 Ray workers, cold (``collect()``) and warm."""
    import ray

    from safe_bc.distributed.runtime import ensure_ray

    ensure_ray()
    cold: dict[int, list[float]] = {1: [], 2: []}
    warm: dict[int, list[float]] = {1: [], 2: []}
    startup: dict[int, list[float]] = {1: [], 2: []}
    variants = ["cold 1", "cold 2", "warm 1", "warm 2"]
    try:
        for rep in range(repeats):
            for variant in _order(variants, rep):
                kind, w = variant.split()
                workers = int(w)
                if kind == "cold":
                    cold[workers].append(_collect_cold(workers, sizes, seed))
                else:
                    sps, up = _collect_warm(workers, sizes, seed)
                    warm[workers].append(sps)
                    startup[workers].append(up)
    finally:
        ray.shutdown()  # reaps Ray's processes so that RUSAGE_CHILDREN sees them
    work = f"{sizes.collect_episodes} episodes x {sizes.collect_steps} steps, fresh dir each run"
    cold_note = f"collect(): CollectReport.steps_per_s incl. actor start-up; {work}"
    warm_note = f"actors started and ready before the clock; {work}"
    up_note = "actor creation until every constructor (imports, env, expert) has returned"
    return [
        _self_row("collect", "1 worker, cold", cold[1], "steps/s", cold_note),
        _row(
            "collect", "2 workers, cold", cold[2], "steps/s", ("1 worker, cold", cold[1]), cold_note
        ),
        _self_row("collect", "1 worker, warm", warm[1], "steps/s", warm_note),
        _row(
            "collect", "2 workers, warm", warm[2], "steps/s", ("1 worker, warm", warm[1]), warm_note
        ),
        _self_row("collect", "actor start-up, 1 worker", startup[1], "s", up_note),
        _row(
            "collect",
            "actor start-up, 2 workers",
            startup[2],
            "s",
            ("actor start-up, 1 worker", startup[1]),
            up_note,
        ),
    ]
