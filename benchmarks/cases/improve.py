"""The ``improve`` case of ``python -m benchmarks.bench``."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from benchmarks.bench import (
    Sizes,
    _order,
    _row,
    _self_row,
)
from benchmarks.cases.eval import untrained_source

IMPROVE_ENVS = 4
"""Envs of the improvement-rollout case (the episodes per iteration of
``tune_jobs/compare/improve.py``'s ``improve_carracing``)."""


def bench_improve(sizes: Sizes, repeats: int, seed: int) -> list[dict[str, Any]]:
    """Env steps/s of an improvement run's lockstep rollout: envs on Ray actors vs in-process.

    The loop is the learner's: one batched forward pass of a BC net for the live envs, then
    the env group steps them (:class:`safe_bc.methods.improve.LocalEnvs` or
    :class:`safe_bc.distributed.envs.RayEnvs`). Actor start-up and the tracks' generation
    (the reset) are outside the clock.
    """
    from safe_bc.distributed.envs import RayEnvs
    from safe_bc.distributed.runtime import cluster_cpus, ensure_ray
    from safe_bc.methods.improve import LocalEnvs

    ensure_ray()
    n = IMPROVE_ENVS
    workers = max(1, min(n, int(cluster_cpus())))
    policy = untrained_source(seed).build()
    makers: dict[str, Callable[[], Any]] = {
        "in-process": lambda: LocalEnvs("CarRacing-v3", n),
        f"{workers} Ray actors": lambda: RayEnvs("CarRacing-v3", n, workers),
    }
    rates: dict[str, list[float]] = {name: [] for name in makers}
    for rep in range(repeats):
        for name in _order(list(makers), rep):
            group = makers[name]()
            obs = group.reset([seed + i for i in range(n)])
            index = list(range(n))
            t0 = time.perf_counter()
            for _ in range(sizes.improve_steps):
                actions = policy.act_batch(np.stack(obs))
                obs = [step[0] for step in group.step(index, actions)]
            rates[name].append(n * sizes.improve_steps / (time.perf_counter() - t0))
            group.close()
    note = (
        f"{n} CarRacing envs x {sizes.improve_steps} lockstep steps, one batched forward pass "
        "of an untrained default BC net per step (the learner's share)"
    )
    base, other = list(makers)
    return [
        _self_row("improve", base, rates[base], "steps/s", note),
        _row("improve", other, rates[other], "steps/s", (base, rates[base]), note),
    ]
