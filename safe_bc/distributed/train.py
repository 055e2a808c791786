"""Training several BC agents in parallel: one Ray task per agent, demonstrations shared once."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import ray

from safe_bc.bc import TrainResult
from safe_bc.data.demos import Demonstrations
from safe_bc.distributed.runtime import cpus_per_actor, ensure_ray
from safe_bc.methods.experiment import RunConfig, train_run
from safe_bc.progress import progress_bar
from safe_bc.selection import Selection


def _train_one(
    demos: Demonstrations, run: RunConfig, bounds: Any, validation: Demonstrations | None
) -> tuple[TrainResult, Selection]:
    return train_run(demos, run, action_bounds=bounds, validation=validation)


def train_many(
    demos: Demonstrations,
    runs: Sequence[RunConfig],
    *,
    workers: int = 2,
    action_bounds: Any = None,
    progress: bool = True,
    on_done: Callable[[int, TrainResult], None] | None = None,
    validation: Demonstrations | None = None,
) -> list[tuple[TrainResult, Selection]]:
    """Train one agent per run config, ``workers`` at a time; results in ``runs`` order.
    ``on_done(i, result)`` is called as soon as agent ``i`` has finished (e.g. to store it,
    so that a killed driver keeps the agents finished so far); ``validation``: held-out
    demonstrations whose loss every agent's curve records (the weights are the same without).

    Each agent trains with one torch thread (set in its config), so the weights are
    the same as a sequential run's with one thread: the seed alone decides them.
    """
    runs = [
        dataclasses.replace(
            r, bc=dataclasses.replace(r.bc, train=dataclasses.replace(r.bc.train, num_threads=1))
        )
        for r in runs
    ]
    ensure_ray()
    task = ray.remote(_train_one).options(num_cpus=cpus_per_actor(workers), max_retries=2)
    demos_ref = ray.put(demos)
    validation_ref = None if validation is None else ray.put(validation)
    refs = [task.remote(demos_ref, r, action_bounds, validation_ref) for r in runs]
    index = {ref: i for i, ref in enumerate(refs)}
    results: list[Any] = [None] * len(refs)
    pending = list(refs)
    with progress_bar(show=progress, total=len(refs), desc="train", unit="agent") as bar:
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            results[index[done[0]]] = ray.get(done[0])
            if on_done is not None:
                on_done(index[done[0]], results[index[done[0]]][0])
            bar.update(1)
    return results
