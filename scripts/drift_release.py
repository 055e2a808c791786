"""Where should a drift stop? Sweep ``PerturbationConfig.release_distance`` on the default
demonstration tracks and report the closest approach to the grass per dimension, the wheel
contacts and the reward (the measurements behind the default of 6 px).

    python -m scripts.drift_release                     # 5 episodes x 5 settings, ~4 min
    python -m scripts.drift_release --releases 0 6 --episodes 2

Writes ``results/demos/release_sweep.md`` and ``.parquet`` (with provenance).
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
import pandas as pd

from safe_bc.collection import EpisodeMaker
from safe_bc.data.store import write_table_atomic, write_text_atomic
from safe_bc.provenance import run_metadata
from safe_bc.report import markdown_table
from safe_bc.tasks import task_defaults


def sweep(releases: list[float], episodes: int) -> pd.DataFrame:
    """One row per release distance: closest distance per dimension over the scored steps of
    ``episodes`` default demonstration episodes, fewest wheels on the road, mean reward."""
    base = task_defaults("carracing").collect_config()
    rows = []
    for release in releases:
        pert = dataclasses.replace(base.perturbation, release_distance=release)
        maker = EpisodeMaker(dataclasses.replace(base, perturbation=pert))
        wheels: list[int] = []
        step = maker.env.step

        def logged(action, _step=step, _wheels=wheels):
            out = _step(action)
            _wheels.append(out[-1]["wheels_on_road"])
            return out

        maker.env.step = logged  # type: ignore[method-assign]
        try:
            eps = [maker.make(i) for i in range(episodes)]
        finally:
            maker.close()
        safety = np.concatenate([e.safety[~e.warmup] for e in eps])
        closest = safety.min(axis=0)
        row = {"release_distance": release, "episodes": episodes}
        row.update({f"closest_{d}": float(c) for d, c in zip(eps[0].safety_dims, closest,
                                                            strict=True)})  # fmt: skip
        row.update(
            fewest_wheels_on_road=int(min(wheels)),
            offroad_frames=int(sum(e.offroad.sum() for e in eps)),
            reward_mean=float(np.mean([e.total_reward for e in eps])),
        )
        rows.append(row)
        print(row, flush=True)
    return pd.DataFrame(rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--releases", type=float, nargs="+", default=[0.0, 3.0, 4.5, 6.0, 10.0])
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--out", type=Path, default=Path("results/demos"))
    args = parser.parse_args(argv)
    table = sweep(args.releases, args.episodes)
    meta = run_metadata(releases=args.releases, episodes=args.episodes, collection="default")
    args.out.mkdir(parents=True, exist_ok=True)
    write_table_atomic(args.out / "release_sweep.parquet", table, meta)
    head = [
        "release distance (px)",
        "closest left",
        "closest front",
        "closest right",
        "fewest wheels on road",
        "off-road frames",
        "reward",
    ]
    rows = [
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
    lines = [markdown_table(rows, head)]
    lines += ["", f"{args.episodes} default demonstration episodes per row; code "
              f"{meta['git_revision']}; command `{meta['command']}`", ""]  # fmt: skip
    write_text_atomic(args.out / "release_sweep.md", "\n".join(lines))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
