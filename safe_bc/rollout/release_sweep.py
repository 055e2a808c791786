"""Where should a drift stop? Demonstrations collected at several release distances.

The drift perturbation (:mod:`safe_bc.tasks.carracing.perturb`) pushes the car towards one edge
and releases it once the frame's distance to the grass on that side falls to
``PerturbationConfig.release_distance`` px. A :class:`ReleaseSweep` collects ``episodes``
default demonstration episodes (the task's default collection, its tracks and noise) per
release distance and keeps, per distance: the closest approach to the grass per safety
dimension over the scored steps, the fewest wheels on the road, the off-road frames and the
mean reward: the measurements behind the default of 6 px (``results/demos/release_sweep.md``,
cited by ``docs/defaults.md``).

Run: ``python -m scripts.release_sweep [FILE]`` (``FILE`` defines ``SWEEP =
ReleaseSweep(...)``; default ``tune_jobs/sweeps/drift_release.py``). Writes
``OUT/release_sweep.parquet`` (with provenance) and ``release_sweep.md``, a function of the
parquet alone (:func:`render_markdown`).
"""

from __future__ import annotations

import dataclasses
import runpy
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pandas as pd

from safe_bc.data.episode import Episode
from safe_bc.report import markdown_table
from safe_bc.tasks.env_config import DEFAULT_RENDERER, Renderer

DEFAULT_FILE = Path("tune_jobs/sweeps/drift_release.py")
"""The committed sweep's settings."""

STEM = "release_sweep"
"""Output stem: ``OUT/release_sweep.parquet`` and ``.md``."""


@dataclass(frozen=True)
class ReleaseSweep:
    """Release distances x default demonstration episodes (see the module doc)."""

    releases: tuple[float, ...] = (0.0, 3.0, 4.5, 6.0, 10.0)
    """``PerturbationConfig.release_distance`` values, px, one table row each."""
    episodes: int = 5
    """Default demonstration episodes (ids ``0..episodes-1``) per release distance."""
    out: Path = Path("results/demos")
    """Where ``release_sweep.parquet`` and ``.md`` go."""
    renderer: Renderer = DEFAULT_RENDERER
    """The renderer that draws the episodes (the release reads the frame's safety distance)."""

    def __post_init__(self) -> None:
        if not self.releases or any(not (r >= 0) for r in self.releases):
            raise ValueError(f"releases must be distances >= 0, got {self.releases}")
        if self.episodes < 1:
            raise ValueError(f"episodes must be >= 1, got {self.episodes}")


def release_row(
    release: float, episodes: Sequence[Episode], wheels: Sequence[int]
) -> dict[str, Any]:
    """One table row: the closest distance per safety dimension over the scored (not
    warm-up) steps of ``episodes``, the fewest of ``wheels`` (wheels on the road after each
    step), the off-road frames and the mean reward."""
    safety = np.concatenate([e.safety[~e.warmup] for e in episodes])
    closest = safety.min(axis=0)
    row: dict[str, Any] = {"release_distance": float(release), "episodes": len(episodes)}
    row.update(
        {f"closest_{d}": float(c) for d, c in zip(episodes[0].safety_dims, closest, strict=True)}
    )
    row.update(
        fewest_wheels_on_road=int(min(wheels)),
        offroad_frames=int(sum(e.offroad.sum() for e in episodes)),
        reward_mean=float(np.mean([e.total_reward for e in episodes])),
    )
    return row


def render_markdown(table: pd.DataFrame, meta: dict[str, Any]) -> str:
    """``release_sweep.md`` from the table and its provenance."""
    cells = [
        [
            f"{r.release_distance:g}",
            f"{r.closest_left:.2f}",
            f"{r.closest_front:.2f}",
            f"{r.closest_right:.2f}",
            r.fewest_wheels_on_road,
            r.offroad_frames,
            f"{r.reward_mean:.1f}",
        ]
        for r in table.itertuples()
    ]
    head = ["release distance (px)", "closest left", "closest front", "closest right",
            "fewest wheels on road", "off-road frames", "reward"]  # fmt: skip
    episodes = ", ".join(str(n) for n in dict.fromkeys(table["episodes"]))
    return "\n".join(
        [
            markdown_table(cells, head),
            "",
            f"{episodes} default demonstration episodes per row; code "
            f"{meta['git_revision']}; command `{meta['command']}`",
            "",
        ]
    )


class _WheelLog(gym.Wrapper):
    """Keeps ``info["wheels_on_road"]`` of every step (the info contract of
    :mod:`.wrapper`; demonstration episodes do not store it)."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.wheels: list[int] = []

    def step(self, action: Any) -> Any:
        out = self.env.step(action)
        self.wheels.append(int(out[-1]["wheels_on_road"]))
        return out


def collect_release(
    release: float, episodes: int, renderer: Renderer = DEFAULT_RENDERER
) -> tuple[list[Episode], list[int]]:
    """Default demonstration episodes ``0..episodes-1`` drawn by ``renderer`` with the drift
    released at ``release`` px (in this process), and the wheels on the road after each of
    their steps."""
    from safe_bc.rollout.collect import CollectConfig, EpisodeMaker
    from safe_bc.tasks import task_defaults

    base = CollectConfig.for_task(task_defaults("carracing", renderer))
    pert = dataclasses.replace(base.perturbation, release_distance=release)
    maker = EpisodeMaker(dataclasses.replace(base, perturbation=pert))
    log = _WheelLog(maker.env)
    maker.env = log
    try:
        return [maker.make(i) for i in range(episodes)], log.wheels
    finally:
        maker.close()


def run_sweep(sweep: ReleaseSweep, *, progress: bool = True) -> pd.DataFrame:
    """Collect every row, write ``OUT/release_sweep.parquet`` and ``.md``; the table."""
    from safe_bc.data.provenance import run_metadata
    from safe_bc.data.store import write_table_atomic, write_text_atomic

    rows = []
    for release in sweep.releases:
        rows.append(release_row(release, *collect_release(release, sweep.episodes, sweep.renderer)))
        if progress:
            print(rows[-1], flush=True)
    table = pd.DataFrame(rows)
    meta = run_metadata(
        releases=list(sweep.releases),
        episodes=sweep.episodes,
        collection="default",
        renderer=sweep.renderer,
    )
    sweep.out.mkdir(parents=True, exist_ok=True)
    write_table_atomic(sweep.out / f"{STEM}.parquet", table, meta)
    text = render_markdown(table, meta)
    write_text_atomic(sweep.out / f"{STEM}.md", text)
    if progress:
        print(text)
    return table


def load_sweep(path: str | Path) -> ReleaseSweep:
    """The ``SWEEP`` of a sweep file."""
    sweep = runpy.run_path(str(path)).get("SWEEP")
    if not isinstance(sweep, ReleaseSweep):
        raise ValueError(f"{path}: defines no SWEEP = ReleaseSweep(...)")
    return sweep
