"""Rollouts of the interactive-training rounds (critical-zone queries, self-imitation) on
persistent Ray actors (the pool of :func:`safe_bc.distributed.pool.run_on_actors`: a dead
actor's tracks run again elsewhere)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

Rollout = Callable[[Any, Sequence[int]], list[Any]]
"""Runs a job on tracks in this process, results in track order:
:func:`safe_bc.methods.queries.rollout.query_tracks`,
:func:`safe_bc.methods.selfimprove.rollout.local_rollouts`."""


class _Roller:
    """One actor: runs a job on its tracks (``rollout(job, seeds)``)."""

    def run(self, rollout: Rollout, boxed: list[Any], seeds: tuple[int, ...]) -> list[Any]:
        import ray

        return rollout(ray.get(boxed[0]), seeds)


class ChunkedRayRollouts:
    """``rollout`` on ``workers`` Ray actors: the tracks in ``workers`` contiguous chunks,
    results in track order (the same as ``rollout`` in-process). A ``RolloutFn`` of
    :mod:`safe_bc.methods.queries.run` and :mod:`safe_bc.methods.selfimprove.run`."""

    def __init__(self, rollout: Rollout, workers: int, actor_cpus: float | None = None) -> None:
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        self.rollout, self.workers, self.actor_cpus = rollout, workers, actor_cpus

    def __call__(self, job: Any, seeds: Sequence[int]) -> list[Any]:
        import ray

        from safe_bc.distributed.pool import run_on_actors
        from safe_bc.distributed.runtime import cpus_per_actor, ensure_ray

        ensure_ray()
        n = min(self.workers, len(seeds))
        size = -(-len(seeds) // n)
        chunks = [tuple(seeds[i : i + size]) for i in range(0, len(seeds), size)]
        boxed = [ray.put(job)]
        cpus = cpus_per_actor(n) if self.actor_cpus is None else self.actor_cpus
        actor_cls = ray.remote(_Roller).options(num_cpus=cpus, max_restarts=0)
        done: dict[tuple[int, ...], list[Any]] = {}
        run_on_actors(
            lambda: actor_cls.remote(),
            n,
            chunks,
            lambda actor, chunk: actor.run.remote(self.rollout, boxed, chunk),
            lambda chunk, value: done.__setitem__(chunk, value),
        )
        return [item for chunk in chunks for item in done[chunk]]
