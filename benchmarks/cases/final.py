"""The ``final`` case of ``python -m benchmarks.bench``."""

from __future__ import annotations

import time
from typing import Any

from benchmarks.bench import (
    Sizes,
    _order,
    _row,
    _self_row,
)
from benchmarks.cases.eval import untrained_source


def bench_final(sizes: Sizes, repeats: int, seed: int) -> list[dict[str, Any]]:
    """Episodes/min of the final phase's evaluation: one actor per CPU vs one actor."""
    from safe_bc.distributed.evaluate import evaluate
    from safe_bc.distributed.runtime import cluster_cpus, ensure_ray
    from safe_bc.rollout.evaluate import EvalConfig

    ensure_ray()
    cpus = max(1, int(cluster_cpus()))
    sources = {"a": untrained_source(seed), "b": untrained_source(seed + 1)}
    rates: dict[int, list[float]] = {1: [], cpus: []}
    for rep in range(repeats):
        for workers in _order(list(rates), rep):
            config = EvalConfig(
                episodes=sizes.final_episodes,
                workers=workers,
                seed=seed,
                max_steps=sizes.eval_steps,
            )
            t0 = time.perf_counter()
            result = evaluate(sources, config, None, progress=False)
            rates[workers].append(60.0 * len(result.episodes) / (time.perf_counter() - t0))
    note = (
        f"evaluate() of 2 untrained default BC nets x {sizes.final_episodes} episodes of <= "
        f"{sizes.eval_steps} steps, actor start-up included (as in the final phase)"
    )
    rows = [_self_row("final", "1 worker", rates[1], "episodes/min", note)]
    if cpus > 1:
        rows.append(
            _row(
                "final",
                f"{cpus} workers (every CPU)",
                rates[cpus],
                "episodes/min",
                ("1 worker", rates[1]),
                note,
            )
        )
    return rows
