"""Stock vs fast CarRacing-v3 rendering speed, measured side by side in one process.

``bench_render`` drives gymnasium's ``CarRacing`` and ``FastCarRacing`` with the same
deterministic controller (pure pursuit along the track with a little seeded steering noise,
so the car mostly stays on the road, which is what demonstrations look like), times only the
``env.step`` calls, and alternates the variants within each repetition so that load from other
processes hits both alike. Compare the ratio, not the absolute numbers.

    python -m benchmarks.bench_render --steps 1000 --repeats 3
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from gymnasium.envs.box2d.car_racing import CarRacing

from safe_bc.tasks.carracing.fast_render import FastCarRacing

__all__ = ["bench_render"]


def _make_env(renderer: str) -> Any:
    """``safe_bc.tasks.make_env`` with this renderer: the env safe_bc steps, safety costs in
    ``info`` (``CarRacingSafety``) and gymnasium's wrappers included."""
    from safe_bc.tasks import make_env
    from safe_bc.tasks.env_config import EnvConfig

    return make_env(EnvConfig(renderer=renderer))  # type: ignore[arg-type]


def _pygame_drawing(env: Any) -> Any:
    """``env`` with the track drawn by pygame's gfxdraw instead of the compiled ports (same
    frames): what the ports gain, measured in the same run."""
    env.unwrapped.compiled_drawing = False
    return env


_VARIANTS: dict[str, Callable[[], Any]] = {"stock": CarRacing, "fast": FastCarRacing}
COST_VARIANTS: dict[str, Callable[[], Any]] = {
    "stock + costs": lambda: _make_env("stock"),
    "fast + costs": lambda: _make_env("fast"),
    "fast, pygame gfxdraw + costs": lambda: _pygame_drawing(_make_env("fast")),
    "raster + costs": lambda: _make_env("raster"),
}
"""``make_env`` with stock gymnasium's renderer, the exact renderer (``"fast"``, its former
name; identical frames), the same with its track drawn by pygame's gfxdraw instead of the
compiled ports (identical frames), and the default approximate ``raster`` renderer: all compute
the pixel safety costs every step."""
BASELINES = {"stock": "stock", "fast": "stock", "stock + costs": "stock + costs"}
BASELINES["fast + costs"] = BASELINES["raster + costs"] = "stock + costs"
BASELINES["fast, pygame gfxdraw + costs"] = "stock + costs"
"""Each variant's baseline: the stock renderer with the same wrappers and cost computation."""


class _PursuitDriver:
    """Cheap privileged controller: steer at a track point a few tiles ahead, hold ~25 units/s."""

    def __init__(self, env: CarRacing, seed: int) -> None:
        self.env = env
        self.rng = np.random.default_rng(seed)
        self.track_xy = np.zeros((0, 2))

    def reset(self) -> None:
        """Re-read the track after ``env.reset()``; shape ``(n_tiles, 2)``."""
        self.track_xy = np.asarray([(x, y) for _, _, x, y in self.env.track], dtype=np.float64)

    def __call__(self) -> np.ndarray:
        """The next action ``[steer, gas, brake]`` (float32, shape ``(3,)``)."""
        car = self.env.car
        assert car is not None
        x, y = car.hull.position
        heading = car.hull.angle
        i = int(np.argmin(np.sum((self.track_xy - (x, y)) ** 2, axis=1)))
        tx, ty = self.track_xy[(i + 4) % len(self.track_xy)]
        dx, dy = tx - x, ty - y
        fx, fy = -np.sin(heading), np.cos(heading)
        lateral = (fx * dy - fy * dx) / (np.hypot(dx, dy) + 1e-6)
        steer = float(np.clip(-2.0 * lateral - 0.1 * car.hull.angularVelocity, -1.0, 1.0))
        steer = float(np.clip(steer + self.rng.normal(0.0, 0.1), -1.0, 1.0))
        speed = float(np.hypot(*car.hull.linearVelocity))
        gas, brake = (0.6, 0.0) if speed < 25.0 else (0.0, 0.1 if speed > 35.0 else 0.0)
        return np.array([steer, gas, brake], dtype=np.float32)


def _time_steps(env: Any, steps: int, seed: int) -> tuple[float, float]:
    """Wall and CPU seconds spent inside ``env.step`` over ``steps`` steps (resets untimed)."""
    driver = _PursuitDriver(env.unwrapped, seed)
    episode = 0
    env.reset(seed=seed)
    driver.reset()
    wall = cpu = 0.0
    for _ in range(steps):
        action = driver()
        c0 = time.process_time()
        t0 = time.perf_counter()
        _, _, terminated, truncated, _ = env.step(action)
        wall += time.perf_counter() - t0
        cpu += time.process_time() - c0
        if terminated or truncated:
            episode += 1
            env.reset(seed=seed + episode)
            driver.reset()
    return wall, cpu


def bench_render(
    steps: int = 1000, repeats: int = 3, seed: int = 0, costs: bool = False
) -> list[dict]:
    """Steps per second of stock and fast CarRacing-v3, interleaved in this process.

    Each repetition runs ``steps`` steps per variant from ``reset(seed=seed)`` with the same
    actions; the variants' order alternates between repetitions. Returns one row per variant:
    ``{"case": "env_step", "variant": "stock" | "fast", "steps_per_s": median,
    "steps_per_s_runs": [...], "ms_per_step": ..., "speedup_vs_stock": ..., "cpu_steps_per_s":
    ..., "cpu_speedup_vs_stock": ..., "steps", "repeats", "seed"}``. Wall-clock ``steps_per_s``
    is the headline; the CPU-time figures (``time.process_time``) are steadier when other
    processes compete for the cores. ``costs`` adds the ``COST_VARIANTS`` (``make_env`` with
    each renderer, safety costs computed every step); each row's ``baseline`` names the
    variant its ``speedup_vs_stock`` is measured against (``BASELINES``).
    """
    if steps < 1 or repeats < 1:
        raise ValueError(f"steps and repeats must be >= 1, got {steps}, {repeats}")
    makers = {**_VARIANTS, **(COST_VARIANTS if costs else {})}
    envs = {name: make() for name, make in makers.items()}
    try:
        for env in envs.values():  # warm-up: imports, font, buffers
            _time_steps(env, 5, seed)
        runs: dict[str, list[float]] = {name: [] for name in envs}
        cpu_runs: dict[str, list[float]] = {name: [] for name in envs}
        names = list(envs)
        for r in range(repeats):
            for name in names if r % 2 == 0 else names[::-1]:
                wall, cpu = _time_steps(envs[name], steps, seed)
                runs[name].append(steps / wall)
                cpu_runs[name].append(steps / cpu)
    finally:
        for env in envs.values():
            env.close()

    medians = {name: statistics.median(values) for name, values in runs.items()}
    cpu_medians = {name: statistics.median(values) for name, values in cpu_runs.items()}
    return [
        {
            "case": "env_step",
            "variant": name,
            "steps_per_s": medians[name],
            "steps_per_s_runs": runs[name],
            "ms_per_step": 1000.0 / medians[name],
            "baseline": BASELINES[name],
            "speedup_vs_stock": medians[name] / medians[BASELINES[name]],
            "cpu_steps_per_s": cpu_medians[name],
            "cpu_speedup_vs_stock": cpu_medians[name] / cpu_medians[BASELINES[name]],
            "steps": steps,
            "repeats": repeats,
            "seed": seed,
        }
        for name in envs
    ]


STEP_PARTS: dict[str, tuple[str, ...]] = {
    "track polygons (compiled gfxdraw ports; pygame's gfxdraw where unavailable)": (
        "gfx_kernels.py",
        "gfxdraw.aapolygon",
        "gfxdraw.filled_polygon",
    ),
    "smoothscale (1000x800 -> 96x96)": ("transform.smoothscale",),
    "Surface.fill (background)": ("'fill' of 'pygame.surface.Surface'",),
    "car and indicators (pygame.draw.polygon)": ("pygame.draw.polygon",),
    "physics (Box2D, car dynamics, contacts)": ("Box2D", "car_dynamics.py", "_contact"),
    "safety costs (CarRacingSafety)": (
        "safe_bc/tasks/carracing/costs.py",
        "safe_bc/tasks/carracing/wrapper.py",
    ),
}
"""Where a step of the default env goes: part -> substrings of cProfile's function labels
(``file:line(function)`` or ``{built-in method ...}``); the rest is "other Python"."""


def step_breakdown(steps: int = 300, seed: int = 0) -> dict[str, float]:
    """Milliseconds per ``env.step`` of the exact renderer's env (``make_env`` with
    ``renderer="exact"`` and the safety costs) in each of :data:`STEP_PARTS` and "other
    Python", from cProfile's own time per function over ``steps`` steps of the pursuit
    driver (after a 60-step warm-up past the zoom-in). The profiler's per-call overhead
    inflates the Python parts; the C parts (drawing, scaling, physics) are close to their
    unprofiled cost."""
    import cProfile
    import pstats

    from safe_bc.tasks import make_env
    from safe_bc.tasks.env_config import EnvConfig

    env = make_env(EnvConfig(renderer="exact"))
    try:
        driver = _PursuitDriver(env.unwrapped, seed)
        env.reset(seed=seed)
        driver.reset()
        for _ in range(60):
            env.step(driver())
        profile = cProfile.Profile()
        for _ in range(steps):
            action = driver()
            profile.enable()
            _, _, terminated, truncated, _ = env.step(action)
            profile.disable()
            if terminated or truncated:
                env.reset(seed=seed + 1)
                driver.reset()
    finally:
        env.close()
    parts = dict.fromkeys([*STEP_PARTS, "other Python"], 0.0)
    for (file, line, name), (_, _, tottime, _, _) in pstats.Stats(profile).stats.items():
        label = f"{file}:{line}({name})"
        part = next(
            (p for p, keys in STEP_PARTS.items() if any(k in label for k in keys)), "other Python"
        )
        parts[part] += 1000.0 * tottime / steps
    return parts


def main(argv: list[str] | None = None) -> None:
    """Print stock vs fast steps/s and their ratio (with ``--costs``, also through
    ``make_env`` with the safety costs)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--costs", action="store_true", help="also make_env with safety costs")
    args = parser.parse_args(argv)
    rows = bench_render(steps=args.steps, repeats=args.repeats, seed=args.seed, costs=args.costs)
    for row in rows:
        runs = ", ".join(f"{v:.0f}" for v in row["steps_per_s_runs"])
        print(
            f"{row['case']:>8} {row['variant']:>12}: {row['steps_per_s']:7.1f} steps/s "
            f"({row['ms_per_step']:.2f} ms/step; runs {runs}; "
            f"CPU time {row['cpu_steps_per_s']:.1f} steps/s)"
        )
    for row in rows:
        if row["baseline"] != row["variant"]:
            print(
                f"{row['variant']} / {row['baseline']} (medians, same run): "
                f"{row['speedup_vs_stock']:.2f}x wall-clock, "
                f"{row['cpu_speedup_vs_stock']:.2f}x CPU time"
            )


if __name__ == "__main__":
    main()
