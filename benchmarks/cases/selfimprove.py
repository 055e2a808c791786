"""The ``selfimprove`` case of ``python -m benchmarks.bench``."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from benchmarks.bench import (
    Sizes,
    _order,
    _row,
    _self_row,
    _untrained_source,
)

SELFIMPROVE_ENVS = 8
"""The lockstep width the ``selfimprove`` case times (``SelfImproveConfig.lockstep_envs``)."""


def bench_selfimprove(sizes: Sizes, repeats: int, seed: int) -> list[dict[str, Any]]:
    """CPU seconds of a self-imitation round's rollouts (training runs, then as many
    validation episodes as tracks): one env at a time (the path before lockstep rollouts)
    against :data:`SELFIMPROVE_ENVS` envs in lockstep with one-row forward passes (the same
    runs bit for bit) and with one batched forward pass, side by side in one process. CPU
    time (``time.process_time``, one torch thread), so a loaded machine moves it less."""

    import torch

    from safe_bc.methods.selfimprove.config import LOOP_PUSHES
    from safe_bc.methods.selfimprove.rollout import ExploreJob, ValidateJob, explore_track
    from safe_bc.tasks import make_env, task_defaults

    torch.set_num_threads(1)
    spec = task_defaults("carracing")
    source = _untrained_source(seed)
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
    cpu: dict[str, list[float]] = {name: [] for name in variants}
    for rep in range(repeats):
        for name in _order(list(variants), rep):
            t0 = time.process_time()
            variants[name]()
            cpu[name].append(time.process_time() - t0)
    runs = len(seeds) * (1 + len(base.pushes)) + len(seeds)
    note = (
        f"{len(seeds)} CarRacing tracks x (1 + {len(base.pushes)} pushes) runs and "
        f"{len(seeds)} validation episodes of at most {sizes.selfimprove_steps} steps "
        f"({runs} episodes), an untrained default BC net, one torch thread; CPU seconds "
        "(env builds included); ratio: CPU time against one env at a time (lower is faster)"
    )
    first, *rest = list(variants)
    return [
        _self_row("selfimprove", first, cpu[first], "CPU s", note),
        *(
            _row("selfimprove", v, cpu[v], "CPU s", (first, cpu[first]), note, paired=True)
            for v in rest
        ),
    ]
