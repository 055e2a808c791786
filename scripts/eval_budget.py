"""Evaluation budget: how many tracks per training seed a comparison needs, from Table 1.

Usage::

    .venv/bin/python -m scripts.eval_budget        # results/ablation/eval_budget/

Table 1 evaluates 8 training seeds x the same 20 tracks per method (a crossed table). For each
of its comparisons (every method paired with plain BC on the same cells, plain BC paired with
the expert on the same tracks, and plain BC's own reward) this splits the cell variance into a
training-seed part, a track part and the rest (:class:`safe_bc.metrics.VarianceComponents`)
and predicts the 95% half-width of the mean for other designs:

* more tracks at the same 8 seeds, and more seeds at the same 20 tracks;
* the same compute as Table 1 spread differently: a training seed costs one training run and
  a track one episode, both priced from the committed ``results/bench.parquet`` (``train_bc``
  samples/s for the default ``TrainConfig``, the BC net's evaluation steps/s times the table's
  mean episode length), so ``seeds = budget / (train + tracks x episode)``.

Writes ``eval_budget.parquet`` (one row per comparison and design), ``eval_budget.md`` and
``eval_budget.png`` under ``--out``. Nothing is rerun; the numbers follow from the tables.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from safe_bc.bc.config import TrainConfig
from safe_bc.data.provenance import run_metadata
from safe_bc.data.store import read_table, write_table_atomic
from safe_bc.metrics import VarianceComponents, cell_table

TRACKS = (2, 5, 10, 20, 40, 80)
"""Tracks per training seed of the predicted designs."""
SEEDS = (3, 8, 16)
"""Training seeds of the predicted designs at Table 1's tracks."""


def comparisons(
    episodes: pd.DataFrame, baseline: str, reference: str, metric: str
) -> dict[str, np.ndarray]:
    """Crossed ``(seeds, tracks)`` tables of each comparison: ``<method> - <baseline>`` on the
    same cells, ``<baseline> - <reference>`` (the reference evaluated once per track) and
    ``<baseline>`` itself."""

    def cells(method: str) -> pd.DataFrame:
        df = episodes[episodes["method"] == method]
        if df.empty:
            raise ValueError(f"no episodes of {method!r} (methods: {sorted(set(episodes.method))})")
        return cell_table(df, metric)

    base = cells(baseline)
    ref = episodes[episodes["method"] == reference].set_index("env_seed")[metric]
    out = {baseline: base.to_numpy(float)}
    out[f"{baseline} - {reference}"] = (base - ref.reindex(base.columns).to_numpy()).to_numpy(float)
    for method in dict.fromkeys(episodes["method"]):
        if method not in (baseline, reference):
            out[f"{method} - {baseline}"] = (cells(method) - base).to_numpy(float)
    return out


def costs(bench: pd.DataFrame, mean_steps: float) -> tuple[float, float]:
    """``(seconds per training run, seconds per evaluation episode)`` from a bench table."""

    def value(case: str, variant: str, unit: str) -> float:
        row = bench[(bench.case == case) & (bench.variant == variant) & (bench.unit == unit)]
        if row.empty:
            raise ValueError(f"bench table has no {case}/{variant} row in {unit}")
        return float(row["value"].iloc[0])

    train = TrainConfig()
    per_run = train.batches * train.batch_size / value("train", "train_bc pipeline", "samples/s")
    return per_run, mean_steps / value("eval", "BC net", "steps/s")


def designs(vc: VarianceComponents, n_seeds: int, n_tracks: int, train_s: float, ep_s: float):
    """Rows of predicted half-widths: ``design`` (``as run``; ``tracks``: more or fewer tracks
    at the same seeds; ``seeds``: more or fewer seeds at the same tracks; ``same compute``),
    ``seeds``, ``tracks``, ``half_width``."""
    budget = n_seeds * (train_s + n_tracks * ep_s)
    rows = [("as run", n_seeds, n_tracks)]
    rows += [("tracks", n_seeds, t) for t in sorted({*TRACKS, 2 * n_tracks})]
    rows += [("seeds", s, n_tracks) for s in sorted({*SEEDS, 2 * n_seeds})]
    rows += [("same compute", budget / (train_s + t * ep_s), t) for t in TRACKS]
    return [
        {"design": d, "seeds": float(s), "tracks": float(t), "half_width": vc.half_width(s, t)}
        for d, s, t in rows
    ]


def plot(table: pd.DataFrame, path: Path, n_tracks: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for name, df in table.groupby("comparison", sort=False):
        at_run = float(df.loc[df.design == "as run", "half_width"].iloc[0])
        for ax, design in zip(axes, ("tracks", "same compute"), strict=True):
            d = df[df.design == design]
            ax.plot(d.tracks, d.half_width / at_run, marker="o", label=name)
    axes[0].set_title("more tracks, the same training seeds")
    axes[1].set_title("the same compute: seeds = budget / (train + tracks x episode)")
    for ax in axes:
        ax.set_xscale("log")
        ax.set_xticks(TRACKS, [str(t) for t in TRACKS])
        ax.minorticks_off()
        ax.set_xlabel("tracks per training seed")
        ax.axvline(n_tracks, color="grey", lw=0.8, ls="--")
        ax.axhline(1.0, color="grey", lw=0.5)
    axes[0].set_ylabel("95% half-width / Table 1's")
    axes[1].legend(fontsize=7, loc="upper center")
    fig.suptitle("Evaluation budget from Table 1's variance components (reward)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--episodes", type=Path, default=Path("results/table1_episodes.parquet"))
    p.add_argument("--bench", type=Path, default=Path("results/bench.parquet"))
    p.add_argument("--baseline", default="alpha=0 (rest=all)")
    p.add_argument("--reference", default="expert")
    p.add_argument("--metric", default="reward")
    p.add_argument("--out", type=Path, default=Path("results/ablation/eval_budget"))
    args = p.parse_args(argv)
    episodes, meta = read_table(args.episodes)
    bench, bench_meta = read_table(args.bench)
    tables = comparisons(episodes, args.baseline, args.reference, args.metric)
    n_seeds, n_tracks = tables[args.baseline].shape
    mean_steps = float(episodes.loc[episodes.method == args.baseline, "steps"].mean())
    train_s, ep_s = costs(bench, mean_steps)
    rows = []
    for name, cells in tables.items():
        vc = VarianceComponents.of(cells)
        head = {"comparison": name, "sd_seed": vc.seed**0.5, "sd_track": vc.track**0.5,
                "sd_residual": vc.residual**0.5}  # fmt: skip
        rows += [{**head, **r} for r in designs(vc, n_seeds, n_tracks, train_s, ep_s)]
    table = pd.DataFrame(rows)
    args.out.mkdir(parents=True, exist_ok=True)
    write_table_atomic(
        args.out / "eval_budget.parquet",
        table,
        run_metadata(
            metric=args.metric, baseline=args.baseline, reference=args.reference,
            train_seconds=train_s, episode_seconds=ep_s, mean_steps=mean_steps,
            source={"episodes": str(args.episodes), "command": meta.get("command"),
                    "git_revision": meta.get("git_revision"), "bench": str(args.bench),
                    "bench_revision": bench_meta.get("provenance", {}).get("git_revision")},
        ),
    )  # fmt: skip
    plot(table, args.out / "eval_budget.png", n_tracks)
    report = markdown(table, n_seeds, n_tracks, train_s, ep_s, args)
    (args.out / "eval_budget.md").write_text(report, encoding="utf-8")
    print(report)
    return 0


def markdown(table: pd.DataFrame, n_seeds: int, n_tracks: int, train_s: float, ep_s: float,
             args: argparse.Namespace) -> str:  # fmt: skip
    """The summary: components and predicted half-widths per comparison."""
    view = []
    for name, df in table.groupby("comparison", sort=False):
        hw = {(r.design, round(r.tracks), round(r.seeds, 1)): r.half_width for r in df.itertuples()}
        same = df[df.design == "same compute"]
        best = same.loc[same.half_width.idxmin()]
        at = hw[("as run", n_tracks, float(n_seeds))]
        view.append({
            "comparison": name,
            "sd seed / track / rest": f"{df.sd_seed.iloc[0]:.1f} / {df.sd_track.iloc[0]:.1f} / "
                                      f"{df.sd_residual.iloc[0]:.1f}",
            f"half-width, {n_seeds}x{n_tracks}": f"{at:.1f}",
            f"{n_seeds}x{2 * n_tracks}": f"{hw[('tracks', 2 * n_tracks, float(n_seeds))]:.1f}",
            f"{2 * n_seeds}x{n_tracks}": f"{hw[('seeds', n_tracks, float(2 * n_seeds))]:.1f}",
            "same compute: best tracks per seed (seeds)":
                f"{best.tracks:.0f} ({best.seeds:.1f}): {best.half_width:.1f}",
        })  # fmt: skip
    return (
        f"# Evaluation budget ({args.metric})\n\n"
        f"From `{args.episodes}` ({n_seeds} training seeds x {n_tracks} tracks per method, "
        f"crossed): the random-effects split of each comparison's cells and the predicted 95% "
        f"half-width of its mean (normal approximation) for other designs. Same compute: a "
        f"training run {train_s:.0f} s, an episode {ep_s:.1f} s (`{args.bench}`).\n\n"
        f"{pd.DataFrame(view).to_markdown(index=False)}\n\n![budget](eval_budget.png)\n"
    )


if __name__ == "__main__":
    sys.exit(main())
