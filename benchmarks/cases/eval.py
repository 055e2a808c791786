"""The ``eval`` case of ``python -m benchmarks.bench``."""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Any

import numpy as np

from benchmarks.bench import (
    PAIRED_NOTE,
    Sizes,
    _order,
    _row,
    _self_row,
)


def untrained_source(seed: int) -> Any:
    """A default-config ``BCNet`` with seeded random weights, as a ``NetSource`` (also the
    policy of the ``final``, ``improve`` and ``selfimprove`` cases)."""
    import torch

    from safe_bc.bc import BCConfig, BCNet, ModelSpec
    from safe_bc.rollout.evaluate import NetSource

    cfg = BCConfig()
    torch.manual_seed(seed)
    model = BCNet(ModelSpec.for_data((96, 96, 3), 3), cfg.preprocess, cfg.network)
    return NetSource.from_model(model, cfg)


def _time_evaluation(source: Any, config: Any, envs: int = 1) -> tuple[float, float, float]:
    """``(episodes/min, steps/s, episodes per CPU-minute)`` of one in-process
    ``evaluate_policies`` call stepping ``envs`` envs in lockstep; the last counts this
    process's CPU time (``time.process_time``, every thread), so with one torch thread it is
    the episodes per minute of one core, steadier than wall time on a loaded machine."""
    from safe_bc.distributed.evaluate import evaluate_policies

    t0, c0 = time.perf_counter(), time.process_time()
    episodes, steps = evaluate_policies(
        {"policy": source}, config, progress=False, envs_per_worker=envs
    )
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    return 60.0 * len(episodes) / seconds, len(steps) / seconds, 60.0 * len(episodes) / cpu


BATCHED_ENVS = 4
"""Envs stepped in lockstep (frames per batched forward pass) in the eval case: the
evaluation's ``LOCKSTEP_ENVS``."""


WIDE_BATCHED_ENVS = 8
"""A wider lockstep for the batched forward, and the episodes of every lockstep timing (so
that each variant runs the same tracks: one wave of 8, two of 4, or 8 one by one)."""


def _time_step_parts(net: Any, steps: int, seed: int) -> dict[str, float]:
    """Mean ms per step of a fast env step, ``BCPolicy.act``, the expert's ``act`` and (per
    frame) ``BCPolicy.act_batch`` and ``act_slots`` (both lockstep forwards) on
    ``BATCHED_ENVS`` copies of the frame, on one expert-driven trajectory (the net acts on the
    same frames; its actions are discarded)."""
    from safe_bc.seeds import heldout_seed
    from safe_bc.tasks import make_env
    from safe_bc.tasks.carracing.expert import CarRacingExpert, ExpertConfig
    from safe_bc.tasks.env_config import EnvConfig

    env = make_env(EnvConfig(renderer="fast"))
    expert, policy = CarRacingExpert(ExpertConfig()), net.build()
    totals = dict.fromkeys(
        ("env", "net", "expert", "net batch", "net slots", "net slots batched"), 0.0
    )
    slots = np.arange(BATCHED_ENVS)
    try:
        obs, _ = env.reset(seed=heldout_seed(seed, 0))
        expert.reset(env, np.random.default_rng(seed))
        policy.reset(env, None)
        policy.reset_slots(BATCHED_ENVS)
        for _ in range(steps):
            t0 = time.perf_counter()
            policy.act(obs, env)
            t1 = time.perf_counter()
            action = expert.act(obs, env)
            t2 = time.perf_counter()
            obs, _, terminated, truncated, _ = env.step(action)
            t3 = time.perf_counter()
            policy.act_batch(np.stack([obs] * BATCHED_ENVS))
            t4 = time.perf_counter()
            policy.act_slots(np.stack([obs] * BATCHED_ENVS), slots)
            t5 = time.perf_counter()
            policy.act_slots(np.stack([obs] * BATCHED_ENVS), slots, "batched")
            t6 = time.perf_counter()
            totals["net"] += t1 - t0
            totals["expert"] += t2 - t1
            totals["env"] += t3 - t2
            totals["net batch"] += (t4 - t3) / BATCHED_ENVS
            totals["net slots"] += (t5 - t4) / BATCHED_ENVS
            totals["net slots batched"] += (t6 - t5) / BATCHED_ENVS
            if terminated or truncated:
                break
    finally:
        env.close()
    return {k: 1000.0 * v / steps for k, v in totals.items()}


def bench_eval(sizes: Sizes, repeats: int, seed: int) -> list[dict[str, Any]]:
    """``evaluate_policies`` episodes/min (net vs expert) and inference vs env step cost."""
    import torch

    from safe_bc.rollout.evaluate import EvalConfig, ExpertSource
    from safe_bc.tasks.carracing.expert import ExpertConfig

    torch.set_num_threads(1)  # what a 1-CPU Ray evaluation actor gets (OMP_NUM_THREADS=1)
    sources = {"expert": ExpertSource(ExpertConfig()), "BC net": untrained_source(seed)}
    from safe_bc.tasks.env_config import EnvConfig

    config = EvalConfig(  # the exact renderer: the one-env path every ratio is taken against
        episodes=sizes.eval_episodes,
        workers=0,
        seed=seed,
        max_steps=sizes.eval_steps,
        env=EnvConfig(renderer="exact"),
    )
    lock_config = replace(config, episodes=WIDE_BATCHED_ENVS)
    raster_config = replace(lock_config, env=replace(lock_config.env, renderer="raster"))
    _time_step_parts(sources["BC net"], 5, seed)  # warm-up
    eps: dict[str, list[float]] = {name: [] for name in sources}
    sps: dict[str, list[float]] = {name: [] for name in sources}
    # (renderer, envs, lockstep forward): the lockstep variants, timed interleaved
    lock_keys = [
        ("fast", 1, "rows"),
        ("fast", BATCHED_ENVS, "rows"),
        ("raster", 1, "rows"),
        ("raster", BATCHED_ENVS, "rows"),
        ("raster", BATCHED_ENVS, "batched"),
        ("raster", WIDE_BATCHED_ENVS, "batched"),
    ]
    lock: dict[tuple[str, int, str], list[float]] = {k: [] for k in lock_keys}
    lock_cpu: dict[tuple[str, int, str], list[float]] = {k: [] for k in lock_keys}
    parts: dict[str, list[float]] = {k: [] for k in ("env", "net", "expert", "net batch",
                                                     "net slots", "net slots batched")}  # fmt: skip
    for rep in range(repeats):
        for name in _order(list(sources), rep):
            e, s, _ = _time_evaluation(sources[name], config)
            eps[name].append(e)
            sps[name].append(s)
        for key in _order(lock_keys, rep):
            renderer, envs, forward = key
            cfg = raster_config if renderer == "raster" else lock_config
            cfg = replace(cfg, lockstep_forward=forward)
            e, _, per_cpu = _time_evaluation(sources["BC net"], cfg, envs)
            lock[key].append(e)
            lock_cpu[key].append(per_cpu)
        for key, ms in _time_step_parts(sources["BC net"], sizes.act_steps, seed).items():
            parts[key].append(ms)
    share = [n / (n + e) for n, e in zip(parts["net"], parts["env"], strict=True)]
    ev_note = (
        f"evaluate_policies, workers=0 (in-process, no actor start-up), "
        f"{sizes.eval_episodes} episodes x <= {sizes.eval_steps} steps, torch threads 1"
    )
    net_note = "untrained default BCNet (random weights: same compute as a trained one)"
    step_note = f"mean over {sizes.act_steps} expert-driven steps of a fast env; same frames"
    raster_note = (
        "renderer='raster': approximate frames (not the exact env's episodes; "
        "results/ablation/renderer/ measures the difference)"
    )
    lock_base = (
        f"evaluate_policies, workers=0, {WIDE_BATCHED_ENVS} episodes x <= {sizes.eval_steps} "
        f"steps, torch threads 1, {net_note}; envs_per_worker=N: N envs stepped in lockstep "
        "with one act_slots call per step"
    )
    lock_note = f"{lock_base}, the same rows as one env at a time (tested)"
    batched_note = (
        f"{lock_base}, lockstep_forward='batched' (one BCNet.forward over the running envs per "
        "step: the same episodes again on one machine type for the same envs, not the one-env "
        "path's)"
    )
    per_core = "per core: episodes per minute of this process's CPU time (time.process_time)"
    return [
        _self_row("eval", "expert", eps["expert"], "episodes/min", ev_note),
        _row(
            "eval",
            "BC net",
            eps["BC net"],
            "episodes/min",
            ("expert", eps["expert"]),
            f"{ev_note}; {net_note}",
        ),
        _self_row("eval", "expert", sps["expert"], "steps/s", ev_note),
        _row("eval", "BC net", sps["BC net"], "steps/s", ("expert", sps["expert"]), net_note),
        _self_row("eval", "fast env step", parts["env"], "ms/step", step_note),
        _row(
            "eval",
            "BCPolicy.act (1 frame)",
            parts["net"],
            "ms/step",
            ("fast env step", parts["env"]),
            f"{step_note}; {net_note}",
        ),
        _row(
            "eval",
            f"BCPolicy.act_batch ({BATCHED_ENVS} frames), per frame",
            parts["net batch"],
            "ms/step",
            ("BCPolicy.act (1 frame)", parts["net"]),
            f"{step_note}; one plain batched forward pass (the improvement's shield uses it). "
            "Not used for evaluation: it rounds differently from a 1-frame one (other GEMM/conv "
            "kernels), so its actions would not be those of the one-env path",
        ),
        _row(
            "eval",
            f"BCPolicy.act_slots ({BATCHED_ENVS} frames), per frame",
            parts["net slots"],
            "ms/step",
            ("BCPolicy.act (1 frame)", parts["net"]),
            f"{step_note}; what a worker stepping {BATCHED_ENVS} envs in lockstep pays per frame: "
            "every layer per frame (BCNet.forward_rows: no layer is assumed batch-invariant), "
            "bit-identical to act on every CPU by construction",
        ),
        _row(
            "eval",
            f"BCPolicy.act_slots batched ({BATCHED_ENVS} frames), per frame",
            parts["net slots batched"],
            "ms/step",
            ("BCPolicy.act (1 frame)", parts["net"]),
            f"{step_note}; lockstep_forward='batched': the {BATCHED_ENVS} frames preprocessed "
            "together and one forward pass (BCNet.forward); may round differently from act "
            "(safe_bc.policy.LockstepForward)",
        ),
        _self_row(
            "eval",
            "BC net, exact renderer, 1 env",
            lock[("fast", 1, "rows")],
            "episodes/min",
            lock_note,
        ),
        _row(
            "eval",
            f"BC net, exact renderer, {BATCHED_ENVS} envs in lockstep",
            lock[("fast", BATCHED_ENVS, "rows")],
            "episodes/min",
            ("BC net, exact renderer, 1 env", lock[("fast", 1, "rows")]),
            f"{lock_note}; {PAIRED_NOTE}",
            paired=True,
        ),
        *[
            _row(
                "eval",
                f"BC net, raster renderer, {label}",
                lock[("raster", envs, forward)],
                "episodes/min",
                ("BC net, exact renderer, 1 env", lock[("fast", 1, "rows")]),
                f"{lock_note if forward == 'rows' else batched_note}; {raster_note}; {PAIRED_NOTE}",
                paired=True,
            )
            for envs, forward, label in (
                (1, "rows", "1 env"),
                (BATCHED_ENVS, "rows", f"{BATCHED_ENVS} envs in lockstep"),
                (BATCHED_ENVS, "batched", f"{BATCHED_ENVS} envs in lockstep, one batched forward"),
            )
        ],
        _self_row(
            "eval",
            "BC net, exact renderer, 1 env, per core",
            lock_cpu[("fast", 1, "rows")],
            "episodes/min",
            f"{lock_note}; {per_core}",
        ),
        *[
            _row(
                "eval",
                f"BC net, raster renderer, {envs} envs in lockstep with one batched forward, "
                "per core",
                lock_cpu[("raster", envs, "batched")],
                "episodes/min",
                ("BC net, exact renderer, 1 env, per core", lock_cpu[("fast", 1, "rows")]),
                f"{batched_note}; baseline: the exact (fast renderer) one-env path; "
                f"{raster_note}; {per_core}; {PAIRED_NOTE}",
                paired=True,
            )
            for envs in (BATCHED_ENVS, WIDE_BATCHED_ENVS)
        ],
        _row(
            "eval",
            "expert act",
            parts["expert"],
            "ms/step",
            ("fast env step", parts["env"]),
            step_note,
        ),
        _row(
            "eval",
            "inference share of a BC step",
            [100.0 * s for s in share],
            "%",
            note="act / (act + env step), per repetition",
        ),
    ]
