"""The ``train`` case of ``python -m benchmarks.bench``."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from benchmarks.bench import (
    PAIRED_NOTE,
    Sizes,
    _order,
    _paired_ratio,
    _row,
    _self_row,
)

BATCH_SIZE = 64
"""The batch size of the ``train`` and ``stream`` cases' training."""
BARE_DISTINCT_BATCHES = 25
"""The bare torch loop cycles over this many pre-built batches (200 would hold ~400 MB)."""


def run_config(batches: int, seed: int) -> Any:
    """The default agent's ``RunConfig`` with ``batches`` batches of :data:`BATCH_SIZE`, one
    torch thread."""
    from safe_bc.bc import BCConfig, TrainConfig
    from safe_bc.methods.experiment import RunConfig
    from safe_bc.selection import DEFAULT_EPS, SelectionConfig

    train = TrainConfig(batches=batches, batch_size=BATCH_SIZE, seed=seed, num_threads=1)
    return RunConfig(SelectionConfig(eps=DEFAULT_EPS), BCConfig(train=train))


def synthetic_demos(n: int, seed: int = 0, episode_len: int = 250) -> Any:
    """``n`` random ``96x96x3 uint8`` frames with random in-bounds actions and costs."""
    from safe_bc.data.demos import Demonstrations

    rng = np.random.default_rng(seed)
    actions = np.stack(
        [rng.uniform(-1, 1, n), rng.uniform(0, 1, n), rng.uniform(0, 1, n)], axis=1
    ).astype(np.float32)
    costs = rng.uniform(0, 40, (n, 3)).astype(np.float32)
    steps = np.arange(n, dtype=np.int64) % episode_len
    episodes = np.arange(n, dtype=np.int64) // episode_len
    return Demonstrations(
        observations=rng.integers(0, 256, (n, 96, 96, 3), dtype=np.uint8),
        actions=actions,
        costs=costs,
        safety=40 - costs,
        episode_ids=episodes,
        steps=steps,
        seeds=episodes,
        warmup=np.zeros(n, bool),
        safety_dims=("left", "front", "right"),
    )


def _prebuilt_batches(demos: Any, config: Any, n: int) -> list[tuple[Any, Any]]:
    """``n`` preprocessed ``(inputs, targets)`` batches drawn by the run's own sampler."""
    from safe_bc.bc import BatchBuilder, sampler_for
    from safe_bc.methods.experiment import select_for

    sampler = sampler_for(select_for(demos, config.selection), config.bc.train)
    builder = BatchBuilder(demos, config.bc.preprocess)
    rows = [sampler.sample() for _ in range(n)]
    return [(builder.inputs(r), builder.targets(r)) for r in rows]


def _bare_loop(demos: Any, config: Any, batches: list[tuple[Any, Any]]) -> float:
    """Samples/s of the training step alone: same net, init, Adam, loss and torch settings
    as ``train_bc``, cycling over pre-built batches."""
    import torch

    from safe_bc.bc import BCNet, ModelSpec
    from safe_bc.bc.train import torch_settings

    cfg = config.bc
    spec = ModelSpec.for_data(demos.observations.shape[1:], demos.actions.shape[1])
    n_batches = cfg.train.batches
    with torch_settings(cfg.train.num_threads):
        torch.manual_seed(cfg.train.seed)
        model = BCNet(spec, cfg.preprocess, cfg.network)
        optimizer = torch.optim.Adam(
            model.parameters(), lr=cfg.train.lr, weight_decay=cfg.train.weight_decay
        )
        weights = torch.full((spec.action_dim,), 1.0 / spec.action_dim)
        model.train()
        start = time.perf_counter()
        for step in range(n_batches):
            x, y = batches[step % len(batches)]
            loss = ((model(x) - y).square() * weights).sum(dim=1).mean()
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            loss.item()  # train_bc reads the loss every step too
        seconds = time.perf_counter() - start
    return n_batches * cfg.train.batch_size / seconds


def bench_train(sizes: Sizes, repeats: int, seed: int) -> list[dict[str, Any]]:
    """``train_bc`` (sampler + preprocessing + gather) vs a bare loop on pre-built batches."""
    from safe_bc.methods.experiment import train_run

    demos = synthetic_demos(sizes.train_frames, seed)
    config = run_config(sizes.train_batches, seed)
    train_run(demos, run_config(2, seed))  # warm-up: the one-off torch._inductor import
    prebuilt = _prebuilt_batches(demos, config, min(sizes.train_batches, BARE_DISTINCT_BATCHES))
    runs: dict[str, list[float]] = {"bare": [], "pipeline": []}
    with_prepare: list[float] = []  # the same runs, frame preprocessing before the loop included
    repeats = max(repeats, sizes.train_min_repeats)
    for rep in range(repeats):
        for variant in _order(list(runs), rep):
            if variant == "pipeline":
                result = train_run(demos, config)[0]
                runs[variant].append(result.samples_per_s)
                samples = sizes.train_batches * BATCH_SIZE
                with_prepare.append(samples / (result.seconds + result.prepare_seconds))
            else:
                runs[variant].append(_bare_loop(demos, config, prebuilt))
    work = (
        f"{sizes.train_batches} batches x {BATCH_SIZE}, {sizes.train_frames} random frames, "
        "default net, torch threads 1, deterministic algorithms"
    )
    overhead = 1.0 / _paired_ratio(runs["pipeline"], runs["bare"]) - 1.0
    return [
        _self_row(
            "train",
            "bare torch loop",
            runs["bare"],
            "samples/s",
            f"{work}; cycles {len(prebuilt)} pre-built, preprocessed batches",
        ),
        _row(
            "train",
            "train_bc pipeline",
            runs["pipeline"],
            "samples/s",
            ("bare torch loop", runs["bare"]),
            f"{work}; data pipeline adds {100 * overhead:+.0f}% time per batch (the frames "
            f"are preprocessed before the loop, as the bare loop's batches are pre-built); "
            f"{PAIRED_NOTE}",
            paired=True,
        ),
        _row(
            "train",
            "train_bc incl. preprocessing",
            with_prepare,
            "samples/s",
            ("bare torch loop", runs["bare"]),
            f"{work}; the same runs, timed from the start of the frame preprocessing "
            f"({sizes.train_frames} frames, once each) to the end of the loop; {PAIRED_NOTE}",
            paired=True,
        ),
    ]
