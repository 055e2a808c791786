"""The observation ablation's analysis: the default it supports, paired and copycat tables,
Markdown and figure, from its episode table (an analysis of committed tables).

Usage::

    python -m scripts.observation_choice   # after: make ablation
    python -m scripts.observation_choice --out results/ablation/budget --name budget \\
        --episodes results/ablation/budget/budget_episodes.parquet \\
        --title "Training budget (CarRacing, plain BC)"

The episodes come from the comparison runner (``tune_jobs/compare/observation.py``'s
``observation``, ``budget``, ``network``, ...: rows named by cell, masked rows
``<cell>/steer_masked``) or, for the committed tables made before it, from
``results/ablation/*/episodes.parquet`` (``cell`` and ``view`` columns); both read the same.
Per (cell, view): crossed means and CIs (:func:`safe_bc.metrics.summarize_crossed`);
paired differences of every cell to the baseline and to the chosen cell
(:func:`safe_bc.metrics.paired_crossed`); masked minus full per bar-kept cell (the copycat
check); bootstrap seed 0. :func:`choose`: among the cells with the most training seeds (a
screen never decides), the fewest episodes beyond d_s, then the highest reward.

Writes ``OUT/summary.parquet``, ``OUT/paired.parquet``, ``OUT/copycat.parquet``,
``OUT/paired_chosen.parquet``, ``OUT/<name>.md`` and ``OUT/<name>.png``.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from safe_bc.metrics import paired_crossed

MASKED = "/steer_masked"
"""Suffix of the runner's rows evaluated with the steering indicator masked."""

REPORT_METRICS = (
    "reward",
    "any_violation",
    "violation_steps",
    "offroad_steps",
    "safety_mean",
    "steer_autocorr",
    "steer_change",
)


def cells_and_views(episodes: pd.DataFrame, training: pd.DataFrame | None = None) -> pd.DataFrame:
    """``cell``, ``view`` (``full`` / ``steer_masked``) and ``final_loss`` per episode: as they
    are in the committed tables made before the runner, else from the runner's ``method`` (and
    its training table)."""
    if "cell" in episodes and "view" in episodes:
        return episodes
    masked = episodes["method"].str.endswith(MASKED)
    out = episodes.assign(
        cell=episodes["method"].str.removesuffix(MASKED),
        view=np.where(masked, "steer_masked", "full"),
    )
    if training is not None and len(training):
        loss = training.set_index(["method", "train_seed"])["final_loss"]
        keys = list(zip(out["cell"], out["train_seed"], strict=True))
        out["final_loss"] = [loss.get(k, np.nan) for k in keys]
    else:
        out["final_loss"] = np.nan
    return out


def summarise(episodes: pd.DataFrame, baseline: str) -> tuple[pd.DataFrame, ...]:
    """Per (cell, view): crossed means and CIs; paired differences of every cell to
    ``baseline`` (full view); the masked-minus-full difference per bar-kept cell."""
    from safe_bc.metrics import paired_crossed, summarize_crossed

    summary = summarize_crossed(episodes, ["cell", "view"], REPORT_METRICS)
    full = episodes[episodes["view"] == "full"]
    agents = full[full["cell"] != "expert"]
    paired = paired_crossed(
        agents, baseline, ["reward", "violation_steps", "any_violation"], by="cell"
    )
    copy_rows = []
    for cell, df in episodes[episodes["cell"] != "expert"].groupby("cell", sort=True):
        if "steer_masked" not in set(df["view"]):
            continue
        d = paired_crossed(df, "full", ["reward", "violation_steps", "steer_change"], by="view")
        copy_rows.append(d.assign(cell=cell))
    copycat = pd.concat(copy_rows, ignore_index=True) if copy_rows else pd.DataFrame()
    return summary, paired, copycat


def choose(summary: pd.DataFrame) -> str:
    """The default the measurement supports: among the agents' cells with the most training
    seeds (a screened cell with fewer seeds never decides), the fewest episodes beyond d_s,
    then the highest reward (the study maximises reward subject to safety)."""
    agents = summary[(summary["view"] == "full") & (summary["cell"] != "expert")]
    agents = agents[agents["n_train_seeds"] == agents["n_train_seeds"].max()]
    best = agents.sort_values(["any_violation", "reward"], ascending=[True, False])
    return str(best["cell"].iloc[0])


def _ci(row: pd.Series, m: str, digits: int = 1, prefix: str = "") -> str:
    mean, lo, hi = row[f"{prefix}{m}"], row[f"{prefix}{m}_lo"], row[f"{prefix}{m}_hi"]
    return f"{mean:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


def _paired_tab(paired: pd.DataFrame, reference: str) -> pd.DataFrame:
    if paired.empty:  # a single cell: nothing to pair
        return pd.DataFrame({"observation": [], f"reward - {reference}": []})
    d = paired.sort_values("d_reward", ascending=False)
    rows = list(d.iterrows())
    return pd.DataFrame(
        {
            "observation": d["cell"],
            f"reward - {reference}": [_ci(r, "reward", prefix="d_") for _, r in rows],
            "steps beyond d_s": [_ci(r, "violation_steps", prefix="d_") for _, r in rows],
            "share of episodes beyond d_s": [
                _ci(r, "any_violation", 2, prefix="d_") for _, r in rows
            ],
            "seeds better": [f"{r.seeds_better}/{r.n_seeds_paired}" for r in d.itertuples()],
        }
    )


def markdown(
    summary: pd.DataFrame,
    paired: pd.DataFrame,
    paired_chosen: pd.DataFrame,
    copycat: pd.DataFrame,
    episodes: pd.DataFrame,
    meta: dict[str, Any],
    baseline: str,
    chosen: str,
    title: str,
) -> str:
    full = summary[summary["view"] == "full"].sort_values("reward", ascending=False)
    counts = (
        episodes[episodes["view"] == "full"]
        .groupby("cell")["any_violation"]
        .agg(lambda s: f"{int(s.sum())}/{len(s)}")
    )
    loss = episodes[episodes["view"] == "full"].groupby("cell")["final_loss"].mean()
    table = pd.DataFrame(
        {
            "observation": full["cell"],
            "seeds x tracks": [f"{r.n_train_seeds} x {r.n_tracks}" for r in full.itertuples()],
            "reward": [_ci(r, "reward") for _, r in full.iterrows()],
            "episodes beyond d_s": [counts[c] for c in full["cell"]],
            "steps beyond d_s / episode": [_ci(r, "violation_steps") for _, r in full.iterrows()],
            "off-road steps / episode": [_ci(r, "offroad_steps") for _, r in full.iterrows()],
            "safety mean (px)": [_ci(r, "safety_mean", 2) for _, r in full.iterrows()],
            "final loss": [
                f"{loss[c]:.4f}" if c in loss and np.isfinite(loss[c]) else "" for c in full["cell"]
            ],
        }
    )
    diff, diff_chosen = _paired_tab(paired, baseline), _paired_tab(paired_chosen, chosen)
    follow = summary[summary["view"].isin(["full", "steer_masked"])]
    if len(copycat):  # with masked runs, the cells that have them; else every cell
        follow = follow[follow["cell"].isin(set(copycat["cell"]) | {"expert"})]
    follow_tab = pd.DataFrame(
        {
            "observation": follow["cell"],
            "view": follow["view"],
            "steering lag-1 autocorrelation": [
                _ci(r, "steer_autocorr", 3) for _, r in follow.iterrows()
            ],
            "mean |steering change|": [_ci(r, "steer_change", 3) for _, r in follow.iterrows()],
        }
    )
    mask_tab = (
        pd.DataFrame(
            {
                "observation": copycat["cell"],
                "reward, masked - full": [
                    _ci(r, "reward", prefix="d_") for _, r in copycat.iterrows()
                ],
                "steps beyond d_s, masked - full": [
                    _ci(r, "violation_steps", prefix="d_") for _, r in copycat.iterrows()
                ],
            }
        )
        if len(copycat)
        else pd.DataFrame()
    )
    lines = [
        f"# {title}",
        "",
        f"Plain behaviour cloning (alpha 0, conv channels {meta['channels']}, "
        f"{meta['batches']} batches of 64) "
        f"on the default demonstrations, {len(meta['seeds'])} training seeds "
        f"({', '.join(map(str, meta['seeds']))}) x {meta['episodes']} selection tracks "
        f"(held-out seed block {meta['eval_seed']}, used by no final table); the expert on "
        "the same tracks. Means with 95% crossed-bootstrap intervals (seeds x tracks). "
        f"Default chosen from this table: **{chosen}** (among the cells with every training "
        "seed: fewest episodes beyond d_s, then highest reward)."
        + (
            f" Cells with {len(meta['screen_seeds'])} seed(s) "
            f"({', '.join(map(str, meta['screen_seeds']))}) are a screen: they are reported "
            "but do not decide."
            if meta.get("screen_cells")
            else ""
        ),
        "",
        table.to_markdown(index=False),
        "",
        f"## Paired differences to `{baseline}`, same seeds x tracks",
        "",
        diff.to_markdown(index=False),
        "",
        *(
            [
                f"## Paired differences to the chosen `{chosen}`, same seeds x tracks",
                "",
                diff_chosen.to_markdown(index=False),
                "",
            ]
            if chosen != baseline
            else []
        ),
        "## Copycat check: does the agent copy its steering from the indicator?",
        "",
        "Each bar-kept agent again on the same tracks with the steering indicator painted "
        "black (`view = steer_masked`); differences masked - full on the same seeds x tracks:",
        "",
        mask_tab.to_markdown(index=False)
        if len(mask_tab)
        else "(not run here: no cell was evaluated with the indicator masked)",
        "",
        "How much steering follows itself (scored steps of every episode):",
        "",
        follow_tab.to_markdown(index=False),
        "",
        f"Episodes: `{meta['source']}` ({meta['source_command']}, code "
        f"{meta['source_revision']}); tables by `{meta['command']}` at {meta['git_revision']}, "
        f"created {meta['created_utc']}; d_s from the demonstrations, eps {meta['eps']} px.",
        "",
    ]
    return "\n".join(lines)


def plot(summary: pd.DataFrame, expert: pd.Series | None, path: Path, title: str) -> Path:
    import matplotlib.pyplot as plt

    from safe_bc.plots import save_figure

    full = summary[(summary["view"] == "full") & (summary["cell"] != "expert")]
    full = full.sort_values("reward")
    masked = summary[summary["view"] == "steer_masked"].set_index("cell")
    y = np.arange(len(full))
    fig, axes = plt.subplots(1, 2, figsize=(11, 0.45 * len(full) + 1.5), sharey=True)
    decides = (full["n_train_seeds"] == full["n_train_seeds"].max()).to_numpy()
    for ax, m, panel in (
        (axes[0], "reward", "reward"),
        (axes[1], "any_violation", "share of episodes beyond d_s"),
    ):
        err = np.vstack([full[m] - full[f"{m}_lo"], full[f"{m}_hi"] - full[m]])
        for keep, style, label in ((decides, "o", "all seeds"), (~decides, "s", "screen (1 seed)")):
            if keep.any():
                ax.errorbar(full[m][keep], y[keep], xerr=err[:, keep], fmt=style,
                            color="tab:blue", mfc="tab:blue" if style == "o" else "white",
                            label=f"full frame, {label}")  # fmt: skip
        mk = full["cell"].map(lambda c, m=m: masked[m].get(c, np.nan) if len(masked) else np.nan)
        ax.plot(mk, y, "x", color="tab:red", label="steering indicator masked")
        if expert is not None:
            ax.axvline(expert[m], color="k", ls="--", lw=1, label="expert")
        ax.set_title(panel)
        ax.grid(alpha=0.3)
    axes[0].set_yticks(y, full["cell"])
    axes[0].legend(loc="lower right", fontsize=8)
    fig.suptitle(f"{title}: seeds x selection tracks, 95% crossed CIs")
    return save_figure(fig, path)


def _describe(episodes: pd.DataFrame, meta: dict[str, Any]) -> dict[str, Any]:
    """What the Markdown says about the run: seeds, screen, budget, network, tracks."""
    agents = episodes[(episodes["view"] == "full") & (episodes["cell"] != "expert")]
    per_cell = agents.groupby("cell")["train_seed"].unique()
    most = max(len(s) for s in per_cell)
    seeds = sorted(int(s) for s in agents["train_seed"].unique())
    screen = sorted(c for c, s in per_cell.items() if len(s) < most)
    screen_seeds = sorted({int(x) for c in screen for x in per_cell[c]})
    if "batches" in episodes:  # the tables made before the runner
        batches = " / ".join(map(str, dict.fromkeys(agents["batches"])))
        channels = " / ".join(dict.fromkeys(agents["channels"]))
    else:
        bcs = [m["bc"] or meta["config"]["bc"] for m in meta["config"]["methods"]
               if m.get("selection")]  # fmt: skip
        batches = " / ".join(dict.fromkeys(str(b["train"]["batches"]) for b in bcs))
        nets = ("-".join(map(str, b["network"]["channels"])) for b in bcs)
        channels = " / ".join(dict.fromkeys(nets))
    return {
        "seeds": seeds,
        "screen_cells": screen,
        "screen_seeds": screen_seeds,
        "batches": batches,
        "channels": channels,
        "episodes": int(agents["env_seed"].nunique()),
        "eval_seed": meta.get("eval_seed", "?"),
        "eps": meta.get("eps", (meta.get("config") or {}).get("eps") or 2.0),
    }


def _file_digests(*paths: Path) -> dict[str, str]:
    """``{path: "sha256:..."}`` of the tables the analysis read (those that exist)."""
    from safe_bc.data.provenance import file_digest

    return {str(p): file_digest(p) for p in paths if p.exists()}


def main(argv: list[str] | None = None) -> int:
    from safe_bc.data.provenance import run_metadata
    from safe_bc.data.store import read_table, write_table_atomic, write_text_atomic

    out = Path("results/ablation/observation")
    p = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    p.add_argument("--episodes", type=Path, default=out / "observation_episodes.parquet")
    p.add_argument("--baseline", default=None, help="cell the others are paired with "
                   "(default: the comparison's reference, or nobar_grey_k1)")  # fmt: skip
    p.add_argument("--name", default="observation", help="stem of the Markdown and figure")
    p.add_argument("--title", default="Observation ablation (CarRacing, plain BC)")
    p.add_argument("--out", type=Path, default=out)
    args = p.parse_args(argv)
    command = shlex.join(["python", "-m", "scripts.observation_choice",
                          *(sys.argv[1:] if argv is None else argv)])  # fmt: skip
    raw, source = read_table(args.episodes)
    training_path = args.episodes.with_name(
        args.episodes.name.replace("_episodes.parquet", "_training.parquet")
    )
    training = read_table(training_path)[0] if training_path.exists() else None
    episodes = cells_and_views(raw, training)
    baseline = args.baseline or source.get("baseline") or (source.get("config") or {}).get(
        "reference") or "nobar_grey_k1"  # fmt: skip
    summary, paired, copycat = summarise(episodes, baseline)
    chosen = choose(summary)
    agents = episodes[(episodes["view"] == "full") & (episodes["cell"] != "expert")]
    paired_chosen = paired_crossed(
        agents, chosen, ["reward", "violation_steps", "any_violation"], by="cell"
    )
    meta = run_metadata(
        **_describe(episodes, source),
        baseline=baseline,
        chosen=chosen,
        bootstrap_seed=0,
        source=str(args.episodes),
        source_command=source.get("command", "?"),
        source_revision=source.get("git_revision", "?"),
    )
    meta["command"] = command
    meta["inputs"] = {
        **source.get("inputs", {}),
        "episodes": _file_digests(args.episodes, training_path),
    }
    args.out.mkdir(parents=True, exist_ok=True)
    for name, frame in (
        ("summary", summary),
        ("paired", paired),
        ("copycat", copycat),
        ("paired_chosen", paired_chosen),
    ):
        write_table_atomic(args.out / f"{name}.parquet", frame, meta)
    text = markdown(
        summary, paired, paired_chosen, copycat, episodes, meta, baseline, chosen, args.title
    )
    write_text_atomic(args.out / f"{args.name}.md", text)
    exp = summary[summary["cell"] == "expert"]
    plot(summary, exp.iloc[0] if len(exp) else None, args.out / f"{args.name}.png", args.title)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
