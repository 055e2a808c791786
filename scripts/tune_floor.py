"""The least wall-clock ``make tune`` can take on 2 cores while the default
study keeps its committed requirements, from the side-by-side runs' own timing tables, and
what cheaper arithmetic would buy per training batch.

The default study's requirements come from an earlier issue ("Safety that holds") and its tests
(``tests/test_study.py``): at least 16 trials at the paper's 2,000 batches, at least 10 tracks
per trial (screened on 3 first), the top 3 retrained with 3 seeds beside plain BC with the same
seeds on 51 fresh tracks. The floor keeps them and removes everything else that can go: one
training seed per trial (the fewest possible; the study uses 2), the cheapest per-training
cost the run measured for every trial (the searcher picks costlier ones), the screened half
evaluated on 3 tracks and the rest on 10, no idle slot and no Ray overhead, and the final phase
as the run measured it. Its ratio to the old run's wall-clock is the best a redesign within the
requirements could reach on this machine, with those runs' evaluation costs taken as fixed
(they were not: ``docs/speed.md``). It is computed for the study the runs ran, the two-seed
design now in ``tune_jobs/default_two_seeds.py``.

``--precision`` also times one training step (Adam, MSE) of the space's networks at batch 64
and 32 in float32 and under bfloat16 autocast, in one process, one thread (what a trial gets):
the per-batch cost lower-precision kernels would save, on this CPU only.

    python -m scripts.tune_floor [--precision]   # writes results/checks/make_tune/floor.md
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import pandas as pd

from safe_bc.data.atomic import write_text_atomic
from safe_bc.data.store import read_table

ROOT = Path(__file__).resolve().parents[1]
RUNS = ROOT / "results/checks/make_tune"


def floor(runs: Path = RUNS) -> dict[str, Any]:
    """The floor's pieces (seconds) from the ``new`` run's tables, and its ratio to ``old``'s
    wall-clock."""
    from safe_bc.study.spec import load_study
    from scripts.tune_side_by_side import run_row

    spec = load_study(ROOT / "tune_jobs/default_two_seeds.py")  # the design it was made for
    timing, meta = read_table(runs / "new/timing.parquet")
    trials, _ = read_table(runs / "new/trials.parquet")
    t = timing.set_index("phase")["seconds"]
    per_training = trials["train_seconds"] / trials["train_seeds"]
    per_episode = t["trial_evaluation"] / float(trials["episodes"].sum())
    final_trainings = spec.final_train_seeds * (spec.final_candidates + 1)  # + plain BC
    screened = spec.trials // 2
    episodes = screened * spec.screen_episodes + (spec.trials - screened) * spec.eval_episodes
    slots = 2

    def tuning(per_train: float) -> float:  # one seed per trial, no idle slot
        return (spec.trials * per_train + episodes * per_episode) / slots

    final = t["final_train"] + t["final_evaluation"]
    fixed = t["ray_start"] + t["demos"] + t["final_summary"]
    old_wall = run_row("old", runs / "old")["wall_s"]
    floor_s = tuning(per_training.min()) + final + fixed
    typical_s = tuning(per_training.mean()) + final + fixed
    return {
        "revision": str(meta.get("provenance", {}).get("git_revision", ""))[:10],
        "trials": spec.trials,
        "final_trainings": final_trainings,
        "trial_episodes": episodes,
        "training_s_cheapest": float(per_training.min()),
        "training_s_mean": float(per_training.mean()),
        "episode_s": float(per_episode),
        "final_phase_s": float(final),
        "fixed_s": float(fixed),
        "floor_s": float(floor_s),
        "typical_s": float(typical_s),
        "old_wall_s": old_wall,
        "floor_ratio": float(floor_s / old_wall),
        "typical_ratio": float(typical_s / old_wall),
        "final_share_of_old": float(final / old_wall),
    }


def step_ms(channels: tuple[int, ...], hidden: int, batch: int, bf16: bool, steps: int) -> float:
    """Milliseconds per training step (Adam, MSE) of one network, one thread."""
    import torch

    from safe_bc.bc.config import NetworkConfig, PreprocessConfig
    from safe_bc.bc.net import BCNet, ModelSpec
    from safe_bc.bc.preprocess import input_shape

    torch.set_num_threads(1)
    torch.manual_seed(0)
    spec, pre = ModelSpec((96, 96, 3), (-1.0, 0.0, 0.0), (1.0, 1.0, 1.0)), PreprocessConfig()
    net = BCNet(spec, pre, NetworkConfig(channels=channels, hidden=hidden))
    x, y = torch.rand(batch, *input_shape(spec.obs_shape, pre)), torch.rand(batch, 3)
    opt = torch.optim.Adam(net.parameters(), 1e-3)
    for k in range(3 + steps):
        if k == 3:
            start = time.perf_counter()
        opt.zero_grad()
        with torch.autocast("cpu", torch.bfloat16, enabled=bf16):
            out = net(x)
        ((out.float() - y) ** 2).mean().backward()
        opt.step()
    return 1000 * (time.perf_counter() - start) / steps


def precision(steps: int = 30) -> pd.DataFrame:
    """Per training step of the space's networks, float32 against bfloat16 autocast."""
    rows = []
    for channels in ((8, 16, 16), (16, 32, 32)):
        for hidden in (64, 256):
            for batch in (32, 64):
                f32 = step_ms(channels, hidden, batch, False, steps)
                b16 = step_ms(channels, hidden, batch, True, steps)
                name = "-".join(map(str, channels))
                row = {"channels": name, "hidden": hidden, "batch": batch}
                rows.append({**row, "float32_ms": f32, "bfloat16_ms": b16, "speed-up": f32 / b16})
    return pd.DataFrame(rows)


def markdown(f: dict[str, Any], prec: pd.DataFrame | None) -> str:
    lines = [
        "# The least `make tune` can take on 2 cores within the default study's requirements",
        "",
        "Made by `python -m scripts.tune_floor"
        + (" --precision" if prec is not None else "")
        + "` from the side-by-side runs' tables (`old/`, `new/` beside this file; new at "
        f"{f['revision']}); see the module's docstring for what the floor keeps and drops.",
        "",
        pd.Series(f, name="value")
        .map(lambda v: f"{v:.3g}" if isinstance(v, float) else v)
        .to_frame()
        .to_markdown(),
        "",
        f"**Floor: {f['floor_s']:.0f} s, {f['floor_ratio']:.2f}x the old run's "
        f"{f['old_wall_s']:.0f} s** (goal 0.5x), only if every trial trained at the cheapest "
        f"setting the run measured ({f['training_s_cheapest']:.1f} s per training); at the "
        f"run's mean ({f['training_s_mean']:.1f} s, the settings the searcher picked) the same "
        f"one-seed design takes **{f['typical_s']:.0f} s, {f['typical_ratio']:.2f}x**. The "
        f"final phase alone ({f['final_trainings']} trainings and 51 fresh tracks per policy) "
        f"is {f['final_share_of_old']:.2f}x.",
        "",
    ]
    if prec is not None:
        lines += [
            "Per training step on this CPU, one thread, float32 against bfloat16 autocast:",
            "",
            prec.to_markdown(index=False, floatfmt=".3g"),
            "",
        ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--precision", action="store_true", help="time float32 vs bfloat16")
    args = parser.parse_args(argv)
    f = floor()
    prec = precision() if args.precision else None
    text = markdown(f, prec)
    write_text_atomic(RUNS / "floor.md", text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
