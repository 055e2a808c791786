"""How the raster renderer's frames and safety costs differ from the exact ones, and what
each renderer costs per step.

Usage::

    python -m scripts.render_accuracy        # results/ablation/renderer/frames.parquet, ...

The exact renderer (``renderer="exact"``, formerly ``"fast"``) spends most of a step in pygame
filling and shrinking a 1000x800 surface; ``renderer="raster"``
(:mod:`safe_bc.tasks.carracing.raster_render`) rasterises the same polygons straight onto a
``96 * supersample`` canvas. This measures, in one run:

1. **Frames and costs** (per supersample factor): the scripted expert (privileged, it never
   reads pixels, so every renderer sees the same trajectory) drives ``--tracks`` fresh tracks
   while the exact env and one raster env per factor take the same actions. Per step after the
   zoom-in: mean absolute pixel difference, share of pixels off by more than 24 in some
   channel, absolute difference of each safety distance (px) and whether the step's
   "beyond d_s" flag (any cost above the demonstrations' limit) agrees.
2. **Speed**: steps/s of stock, exact and each raster factor on the same recorded actions,
   ``--repeats`` alternating repetitions, median; ratios against stock with the same costs.

The factor is chosen by accuracy alone, so that the choice does not move with the machine's
load (the speed ratios of one factor ranged 7x-11x between runs here): the fastest factor
(smallest canvas) whose mean safety-distance error (all three dimensions, after the zoom-in)
is at most 10% of the critical-zone width eps (``selection.DEFAULT_EPS``, 2 px), i.e. one
that moves a state's cost by a tenth of the zone the method is built on. (The 10% was set
after a one-track smoke run.) Writes ``frames.parquet``, ``speed.parquet`` and
``render_accuracy.md`` under ``--out``. What the approximation does to agents is a comparison:
``safe-bc compare tune_jobs/compare/renderer.py --name renderer`` (exact agents on raster frames)
and ``--name pipeline*`` (the whole pipeline on raster frames).
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from safe_bc.data.atomic import write_text_atomic
from safe_bc.data.provenance import run_metadata
from safe_bc.data.store import load_demonstrations, write_table_atomic
from safe_bc.selection import DEFAULT_EPS
from safe_bc.tasks import make_env
from safe_bc.tasks.carracing.raster_render import DEFAULT_SUPERSAMPLE
from safe_bc.tasks.carracing.wrapper import ZOOM_END_T
from safe_bc.tasks.env_config import EnvConfig

FACTORS = (1, 2, 4, 8)
"""Supersample factors compared."""
VISIBLE = 24
"""A pixel counts as visibly different when some channel differs by more than this."""
TOLERANCE = 0.10
"""The rule: the fastest factor whose mean distance error is <= this share of eps."""


def _raster(factor: int, max_steps: int | None = None):
    import gymnasium as gym

    from safe_bc.tasks import register_envs
    from safe_bc.tasks.carracing import RASTER_CARRACING_ID
    from safe_bc.tasks.carracing.wrapper import CarRacingSafety

    register_envs()
    kw = {} if max_steps is None else {"max_episode_steps": max_steps}
    env = gym.make(RASTER_CARRACING_ID, continuous=True, supersample=factor, **kw)
    return CarRacingSafety(env)


def frame_errors(
    tracks: list[int], factors: tuple[int, ...], steps: int, limits: np.ndarray
) -> tuple[pd.DataFrame, dict[int, list[np.ndarray]]]:
    """Per (factor, track) error statistics along the expert's drive; also its actions."""
    from safe_bc.rollout.collect import build_expert
    from safe_bc.tasks import task_defaults

    expert_cfg = task_defaults("carracing").expert
    exact = make_env(EnvConfig(renderer="exact", max_episode_steps=steps))
    rasters = {f: _raster(f, steps) for f in factors}
    rows, actions = [], {}
    for track in tracks:
        expert = build_expert(expert_cfg)
        obs, info = exact.reset(seed=track)
        expert.reset(exact, np.random.default_rng(track))
        for env in rasters.values():
            env.reset(seed=track)
        stats: dict[int, list[tuple]] = {f: [] for f in factors}
        acts = []
        done = False
        while not done:
            action = np.asarray(expert.act(obs, exact), np.float32)
            acts.append(action)
            obs, _, term, trunc, info = exact.step(action)
            done = term or trunc
            scored = exact.unwrapped.t >= ZOOM_END_T - 1e-6
            for f, env in rasters.items():
                r_obs, _, _, _, r_info = env.step(action)
                if not scored:
                    continue
                diff = np.abs(obs.astype(np.int16) - r_obs.astype(np.int16))
                beyond = bool((info["cost"] > limits).any())
                r_beyond = bool((r_info["cost"] > limits).any())
                stats[f].append((diff.mean(), (diff.max(axis=2) > VISIBLE).mean(),
                                 *np.abs(info["safety"] - r_info["safety"]), beyond == r_beyond,
                                 beyond, r_beyond))  # fmt: skip
        actions[track] = acts
        for f, s in stats.items():
            a = np.asarray(s, dtype=float)
            rows.append({"factor": f, "track": track, "steps": len(a),
                         "pixel_abs_diff": a[:, 0].mean(), "visible_share": a[:, 1].mean(),
                         "left_px": a[:, 2].mean(), "front_px": a[:, 3].mean(),
                         "right_px": a[:, 4].mean(), "distance_px": a[:, 2:5].mean(),
                         "distance_px_max": a[:, 2:5].max(), "beyond_agree": a[:, 5].mean(),
                         "beyond_exact": a[:, 6].sum(),
                         "beyond_raster": a[:, 7].sum()})  # fmt: skip
    exact.close()
    for env in rasters.values():
        env.close()
    return pd.DataFrame(rows), actions


def speeds(
    actions: dict[int, list[np.ndarray]], factors: tuple[int, ...], repeats: int
) -> pd.DataFrame:
    """Steps/s of each renderer (with the safety costs) on the recorded actions."""
    variants: dict[str, Any] = {
        "stock": lambda: make_env(EnvConfig(renderer="stock")),
        "fast (exact)": lambda: make_env(EnvConfig(renderer="fast")),
        **{f"raster x{f}": (lambda f=f: _raster(f)) for f in factors},
    }
    envs = {name: build() for name, build in variants.items()}
    times: dict[str, list[float]] = {name: [] for name in envs}
    track, acts = next(iter(actions.items()))
    for _ in range(repeats):
        for name, env in envs.items():  # alternate variants so drift hits them alike
            env.reset(seed=track)
            t0 = time.perf_counter()
            for a in acts:
                env.step(a)
            times[name].append(len(acts) / (time.perf_counter() - t0))
    for env in envs.values():
        env.close()
    base = float(np.median(times["stock"]))
    factor = {f"raster x{f}": f for f in factors}
    return pd.DataFrame([{"variant": n, "factor": factor.get(n, 0),
                          "steps_per_s": float(np.median(v)),
                          "ratio_vs_stock": float(np.median(v)) / base, "runs": v,
                          "steps": len(acts)} for n, v in times.items()])  # fmt: skip


def choose_factor(frames: pd.DataFrame, eps: float = DEFAULT_EPS) -> int:
    """The rule of the module docstring (the smallest factor is the fastest)."""
    err = frames.groupby("factor")["distance_px"].mean()
    ok = err[err <= TOLERANCE * eps]
    if ok.empty:
        raise SystemExit(f"no factor reaches {TOLERANCE * eps:.2f} px: {err.round(3).to_dict()}")
    return int(ok.index.min())


def main(argv: list[str] | None = None) -> int:
    from safe_bc.rollout.evaluate import EvalConfig

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tracks", type=int, default=4, help="expert drives for the frame errors")
    p.add_argument("--steps", type=int, default=600, help="steps per expert drive")
    p.add_argument("--repeats", type=int, default=5, help="speed repetitions")
    p.add_argument("--eval-seed", type=int, default=11,
                   help="the drives take the tracks of seed block eval-seed + 1")  # fmt: skip
    p.add_argument("--demos", type=Path, default=Path("data/demos"))
    p.add_argument("--out", type=Path, default=Path("results/ablation/renderer"))
    args = p.parse_args(argv)
    command = shlex.join(["python", "-m", "scripts.render_accuracy",
                          *(sys.argv[1:] if argv is None else argv)])  # fmt: skip
    limits = load_demonstrations(args.demos).limits
    tracks = EvalConfig(seed=args.eval_seed + 1, episodes=args.tracks).seeds()

    print(f"frames: {len(tracks)} expert drives x {args.steps} steps, factors {FACTORS}")
    frames, actions = frame_errors(tracks, FACTORS, args.steps, limits)
    speed = speeds(actions, FACTORS, args.repeats)
    factor = choose_factor(frames)
    meta = run_metadata(tracks=tracks, steps=args.steps, factors=list(FACTORS), chosen=factor,
                        demos=str(args.demos), limits=[float(x) for x in limits])  # fmt: skip
    meta["command"] = command
    args.out.mkdir(parents=True, exist_ok=True)
    write_table_atomic(args.out / "frames.parquet", frames, meta)
    write_table_atomic(args.out / "speed.parquet", speed, meta)
    write_text_atomic(args.out / "render_accuracy.md", markdown(frames, speed, meta))
    print((args.out / "render_accuracy.md").read_text())
    if factor != DEFAULT_SUPERSAMPLE:  # the evaluation actors build the raster env's default
        raise SystemExit(
            f"the rule chose supersample {factor}, the default is {DEFAULT_SUPERSAMPLE}: set "
            "raster_render.DEFAULT_SUPERSAMPLE to it and rerun"
        )
    return 0


def per_factor(frames: pd.DataFrame, speed: pd.DataFrame) -> pd.DataFrame:
    """Per supersample factor: the frame and cost errors over the drives and the speed ratio."""
    per = frames.groupby("factor").agg(
        steps=("steps", "sum"),
        pixel_abs_diff=("pixel_abs_diff", "mean"),
        visible_share=("visible_share", "mean"),
        distance_px=("distance_px", "mean"),
        distance_px_max=("distance_px_max", "max"),
        beyond_agree=("beyond_agree", "mean"),
        beyond_exact=("beyond_exact", "sum"),
        beyond_raster=("beyond_raster", "sum"),
    )
    per["speed_vs_stock"] = speed[speed.factor > 0].set_index("factor")["ratio_vs_stock"]
    return per.reset_index()


def markdown(frames: pd.DataFrame, speed: pd.DataFrame, meta: dict[str, Any]) -> str:
    """The report."""
    return "\n".join(
        [
            "# What bit-identical frames cost (exact renderer vs raster)",
            "",
            f"Command: `{meta['command']}` at `{meta['git_revision']}`.",
            "",
            "## Frames and safety costs along the expert's drives",
            "",
            f"{len(meta['tracks'])} tracks x <= {meta['steps']} steps (after the zoom-in); "
            "pixel values 0-255; distances in px (the safety costs are max range - distance); "
            "'beyond' = steps with some cost above d_s.",
            "",
            per_factor(frames, speed).to_markdown(index=False, floatfmt=".4g"),
            "",
            "## Speed (steps/s with the safety costs, same actions, one process)",
            "",
            speed[["variant", "steps_per_s", "ratio_vs_stock"]].to_markdown(
                index=False, floatfmt=".3g"
            ),
            "",
            f"Rule: the fastest factor whose mean distance error is at most {TOLERANCE:.0%} of "
            f"eps ({TOLERANCE * DEFAULT_EPS:.2f} px). Chosen: **x{meta['chosen']}**.",
            "",
        ]
    )


if __name__ == "__main__":
    raise SystemExit(main())
