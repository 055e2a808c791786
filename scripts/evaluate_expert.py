"""Evaluate the scripted CarRacing expert on unseen track seeds, with and without perturbation.

Usage::

    .venv/bin/python -m scripts.evaluate_expert            # 20 seeds 10000..10019
    .venv/bin/python -m scripts.evaluate_expert --num-seeds 5 --perturbation drift

Prints one line per episode and, per perturbation mode, the mean / std / min reward,
episode length, offroad steps (all four wheels off the road) and the largest
``|lateral offset|`` from the centre line. The expert's defaults were tuned on
seeds 0..59, never on 10000+.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from safe_bc.envs.factory import CARRACING_ID
from safe_bc.tasks.carracing.costs import pixel_distances
from safe_bc.tasks.carracing.expert import CarRacingExpert, ExpertConfig
from safe_bc.tasks.carracing.geometry import lateral_offset
from safe_bc.tasks.carracing.perturb import Perturbation, PerturbationConfig

DEFAULT_FIRST_SEED = 10_000
"""First evaluation seed; tuning used seeds below 100."""


@dataclass(frozen=True)
class RolloutStats:
    """Summary of one expert episode (``T`` steps executed)."""

    seed: int
    """Track seed passed to ``env.reset``."""
    reward: float
    """Sum of rewards."""
    length: int
    """Steps executed ``T``."""
    offroad_steps: int
    """Steps after which all four wheels were off the road (no tile contact)."""
    min_wheels_on_road: int
    """Fewest wheels touching a road tile at any step (4 = never left the road)."""
    max_abs_lateral: float
    """Largest ``|lateral offset|`` of the hull from the centre line, units."""
    lap_finished: bool
    """Whether the episode ended by completing the lap."""
    actions: np.ndarray
    """``(T, 3) float32`` actions chosen by the expert (the labels)."""
    executed_actions: np.ndarray
    """``(T, 3) float32`` actions sent to the env (perturbed)."""
    lateral: np.ndarray
    """``(T,) float64`` signed lateral offset after each step (positive = right)."""


def make_env(render: bool = True) -> gym.Env:
    """CarRacing-v3 (continuous, 1000-step limit).

    ``render=False`` skips drawing the 96x96 frame (observations are ``None``): the
    physics, rewards and terminations are identical and a step is ~30x faster, which
    is fine for the privileged expert but not for anything that reads pixels.
    """
    if render:
        return gym.make(CARRACING_ID)
    env = gym.make(CARRACING_ID, disable_env_checker=True)
    env.unwrapped._render = lambda mode: None  # type: ignore[method-assign]
    return env


def rollout(
    env: gym.Env,
    seed: int,
    expert: CarRacingExpert | None = None,
    perturbation: Perturbation | None = None,
    rng_seed: int = 0,
    max_steps: int = 1000,
) -> RolloutStats:
    """Run one episode of the expert on track ``seed``; ``rng_seed`` seeds the perturbation."""
    expert = expert if expert is not None else CarRacingExpert()
    rng = np.random.default_rng(rng_seed)
    obs, _ = env.reset(seed=seed)
    expert.reset(env, rng)
    if perturbation is not None:
        perturbation.reset(rng)
    unwrapped = env.unwrapped
    track = np.asarray(unwrapped.track, dtype=np.float64)
    total, offroad, min_wheels, finished = 0.0, 0, 4, False
    actions, executed, lateral = [], [], []
    for t in range(max_steps):
        action = expert.act(obs, env)
        if perturbation is None:
            exe = action
        else:  # the frame's distances let a drift stop short of the grass
            safety = pixel_distances(obs) if obs is not None and t > 0 else None
            exe = perturbation.apply(action, t, rng, safety)
        obs, reward, terminated, truncated, info = env.step(exe)
        total += float(reward)
        wheels = sum(1 for w in unwrapped.car.wheels if w.tiles)
        min_wheels = min(min_wheels, wheels)
        offroad += wheels == 0
        actions.append(action)
        executed.append(exe)
        lateral.append(lateral_offset(track, np.asarray(unwrapped.car.hull.position)))
        if terminated or truncated:
            finished = bool(info.get("lap_finished", False))
            break
    lat = np.asarray(lateral, dtype=np.float64)
    return RolloutStats(
        seed=seed,
        reward=total,
        length=len(actions),
        offroad_steps=int(offroad),
        min_wheels_on_road=int(min_wheels),
        max_abs_lateral=float(np.abs(lat).max()) if lat.size else 0.0,
        lap_finished=finished,
        actions=np.asarray(actions, dtype=np.float32).reshape(-1, 3),
        executed_actions=np.asarray(executed, dtype=np.float32).reshape(-1, 3),
        lateral=lat,
    )


def summarize(stats: Sequence[RolloutStats]) -> dict[str, float]:
    """Aggregate figures over episodes."""
    rewards = np.array([s.reward for s in stats])
    return {
        "episodes": len(stats),
        "reward_mean": float(rewards.mean()),
        "reward_std": float(rewards.std()),
        "reward_min": float(rewards.min()),
        "length_mean": float(np.mean([s.length for s in stats])),
        "laps_finished": int(sum(s.lap_finished for s in stats)),
        "offroad_steps": int(sum(s.offroad_steps for s in stats)),
        "episodes_with_offroad": int(sum(s.offroad_steps > 0 for s in stats)),
        "min_wheels_on_road": int(min(s.min_wheels_on_road for s in stats)),
        "max_abs_lateral": float(max(s.max_abs_lateral for s in stats)),
        "median_max_abs_lateral": float(np.median([s.max_abs_lateral for s in stats])),
    }


def main(argv: Sequence[str] | None = None) -> dict[str, dict[str, float]]:
    """CLI entry point; returns the summaries keyed by perturbation mode."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--first-seed", type=int, default=DEFAULT_FIRST_SEED)
    parser.add_argument("--num-seeds", type=int, default=20)
    parser.add_argument("--max-steps", type=int, default=1000)
    parser.add_argument(
        "--perturbation",
        choices=["both", "none", "drift", "dart"],
        default="both",
        help="'both' = none and the default perturbation (drift)",
    )
    parser.add_argument("--rng-seed", type=int, default=0, help="perturbation rng base seed")
    parser.add_argument(
        "--no-render", action="store_true", help="skip frame drawing (same physics, ~30x faster)"
    )
    args = parser.parse_args(argv)

    modes = ["none", "drift"] if args.perturbation == "both" else [args.perturbation]
    seeds = range(args.first_seed, args.first_seed + args.num_seeds)
    expert = CarRacingExpert(ExpertConfig())
    print(f"expert: {expert.config}")
    env = make_env(render=not args.no_render)
    summaries: dict[str, dict[str, float]] = {}
    try:
        for mode in modes:
            pert = None if mode == "none" else Perturbation(PerturbationConfig(mode=mode))
            if pert is not None:
                print(f"perturbation: {pert.config}")
            stats = []
            t0 = time.perf_counter()
            for k, seed in enumerate(seeds):
                s = rollout(
                    env, seed, expert, pert, rng_seed=args.rng_seed + k, max_steps=args.max_steps
                )
                stats.append(s)
                print(
                    f"[{mode}] seed {seed}: reward {s.reward:7.1f} length {s.length:4d} "
                    f"lap {int(s.lap_finished)} offroad {s.offroad_steps:3d} "
                    f"min_wheels {s.min_wheels_on_road} max|lat| {s.max_abs_lateral:5.2f}",
                    flush=True,
                )
            summary = summarize(stats)
            summaries[mode] = summary
            print(
                f"== {mode}: reward mean {summary['reward_mean']:.1f}"
                f" std {summary['reward_std']:.1f} min {summary['reward_min']:.1f}"
                f" | length mean {summary['length_mean']:.0f}"
                f" | laps {summary['laps_finished']}/{summary['episodes']}"
                f" | offroad steps {summary['offroad_steps']}"
                f" (episodes {summary['episodes_with_offroad']})"
                f" | min wheels {summary['min_wheels_on_road']}"
                f" | max|lat| {summary['max_abs_lateral']:.2f}"
                f" (median per episode {summary['median_max_abs_lateral']:.2f})"
                f" | {time.perf_counter() - t0:.0f} s",
                flush=True,
            )
    finally:
        env.close()
    return summaries


if __name__ == "__main__":
    main()
