"""The observation ablation's analysis: the report step of ``tune_jobs/compare/observation.py``'s
comparisons (``observation``, ``batch``, ``budget``, ``network``, ``resize``), the default a
table supports, with its paired and copycat tables, its Markdown and its figure (pure: tables
in, :class:`~safe_bc.compare.spec.ReportFiles` out).

The comparisons declare ``Report("safe_bc.compare.observation_choice:report",
reads=("episodes", "training"))``: the runner (:func:`safe_bc.compare.run.run_report`) hands
:func:`report` the comparison's table, its episodes (rows named by cell, masked rows
``<cell>/steer_masked``) and its training table, and writes ``OUT/summary.parquet``,
``paired.parquet``, ``copycat.parquet``, ``paired_chosen.parquet``, ``OUT/<name>.md`` (in place
of the table's own Markdown) and ``OUT/<name>.png``; ``safe-bc compare
tune_jobs/compare/observation.py --name NAME --report-only`` reruns only this step from the
tables on disk.

Per (cell, view): crossed means and CIs (:func:`safe_bc.metrics.summarize_crossed`); paired
differences of every cell to the comparison's reference and to the chosen cell
(:func:`safe_bc.metrics.paired_crossed`); masked minus full per bar-kept cell (the copycat
check); bootstrap seed 0. :func:`choose`: among the cells with the most training seeds (a
screen never decides), the fewest episodes beyond d_s, then the highest reward.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from safe_bc.compare.spec import Plot, Read, ReportFiles
from safe_bc.metrics import paired_crossed, summarize_crossed

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
"""The metrics of the summary table."""

PAIRED_METRICS = ["reward", "violation_steps", "any_violation"]
"""The metrics paired with the reference and with the chosen cell."""

DEFAULT_EPS = 2.0
"""The critical-zone width the Markdown names where the comparison recorded none (CarRacing's)."""


def cells_and_views(episodes: pd.DataFrame, training: pd.DataFrame | None = None) -> pd.DataFrame:
    """The runner's episodes with ``cell``, ``view`` (``full`` / ``steer_masked``, from the row
    name) and ``final_loss`` (the cell's training row for that seed; NaN without one)."""
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
    summary = summarize_crossed(episodes, ["cell", "view"], REPORT_METRICS)
    paired = paired_crossed(agents_of(episodes), baseline, PAIRED_METRICS, by="cell")
    copy_rows = []
    for cell, df in episodes[episodes["cell"] != "expert"].groupby("cell", sort=True):
        if "steer_masked" not in set(df["view"]):
            continue
        d = paired_crossed(df, "full", ["reward", "violation_steps", "steer_change"], by="view")
        copy_rows.append(d.assign(cell=cell))
    copycat = pd.concat(copy_rows, ignore_index=True) if copy_rows else pd.DataFrame()
    return summary, paired, copycat


def agents_of(episodes: pd.DataFrame) -> pd.DataFrame:
    """The agents' episodes on the full frame (no expert, no masked view)."""
    return episodes[(episodes["view"] == "full") & (episodes["cell"] != "expert")]


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


def _cells_tab(summary: pd.DataFrame, episodes: pd.DataFrame) -> pd.DataFrame:
    """One line per cell (full frame), highest reward first."""
    full = summary[summary["view"] == "full"].sort_values("reward", ascending=False)
    shown = episodes[episodes["view"] == "full"]
    counts = shown.groupby("cell")["any_violation"].agg(lambda s: f"{int(s.sum())}/{len(s)}")
    loss = shown.groupby("cell")["final_loss"].mean()
    rows = [r for _, r in full.iterrows()]
    return pd.DataFrame(
        {
            "observation": full["cell"],
            "seeds x tracks": [f"{r.n_train_seeds} x {r.n_tracks}" for r in full.itertuples()],
            "reward": [_ci(r, "reward") for r in rows],
            "episodes beyond d_s": [counts[c] for c in full["cell"]],
            "steps beyond d_s / episode": [_ci(r, "violation_steps") for r in rows],
            "off-road steps / episode": [_ci(r, "offroad_steps") for r in rows],
            "safety mean (px)": [_ci(r, "safety_mean", 2) for r in rows],
            "final loss": [
                f"{loss[c]:.4f}" if c in loss and np.isfinite(loss[c]) else "" for c in full["cell"]
            ],
        }
    )


def _follow_tab(summary: pd.DataFrame, copycat: pd.DataFrame) -> pd.DataFrame:
    """How much steering follows itself, per cell and view: with masked runs, the cells that
    have them (and the expert); else every cell."""
    follow = summary[summary["view"].isin(["full", "steer_masked"])]
    if len(copycat):
        follow = follow[follow["cell"].isin(set(copycat["cell"]) | {"expert"})]
    rows = [r for _, r in follow.iterrows()]
    return pd.DataFrame(
        {
            "observation": follow["cell"],
            "view": follow["view"],
            "steering lag-1 autocorrelation": [_ci(r, "steer_autocorr", 3) for r in rows],
            "mean |steering change|": [_ci(r, "steer_change", 3) for r in rows],
        }
    )


def _mask_tab(copycat: pd.DataFrame) -> pd.DataFrame:
    """Masked minus full per bar-kept cell (empty without masked runs)."""
    if not len(copycat):
        return pd.DataFrame()
    rows = [r for _, r in copycat.iterrows()]
    return pd.DataFrame(
        {
            "observation": copycat["cell"],
            "reward, masked - full": [_ci(r, "reward", prefix="d_") for r in rows],
            "steps beyond d_s, masked - full": [
                _ci(r, "violation_steps", prefix="d_") for r in rows
            ],
        }
    )


def _intro(meta: dict[str, Any], chosen: str) -> str:
    """The paragraph under the heading: the run, the tracks, the rule and its choice."""
    screen = (
        f" Cells with {len(meta['screen_seeds'])} seed(s) "
        f"({', '.join(map(str, meta['screen_seeds']))}) are a screen: they are reported "
        "but do not decide."
        if meta.get("screen_cells")
        else ""
    )
    return (
        f"Plain behaviour cloning (alpha 0, conv channels {meta['channels']}, "
        f"{meta['batches']} batches of 64) "
        f"on the default demonstrations, {len(meta['seeds'])} training seeds "
        f"({', '.join(map(str, meta['seeds']))}) x {meta['episodes']} selection tracks "
        f"(held-out seed block {meta['eval_seed']}, used by no final table); the expert on "
        "the same tracks. Means with 95% crossed-bootstrap intervals (seeds x tracks). "
        f"Default chosen from this table: **{chosen}** (among the cells with every training "
        "seed: fewest episodes beyond d_s, then highest reward)." + screen
    )


def markdown(
    summary: pd.DataFrame,
    paired: pd.DataFrame,
    paired_chosen: pd.DataFrame,
    copycat: pd.DataFrame,
    episodes: pd.DataFrame,
    meta: dict[str, Any],
    title: str,
) -> str:
    """The analysis as Markdown: each cell, the paired differences to the baseline and to the
    chosen cell, the copycat check, then where the episodes came from and which command made
    the tables (``meta``: :func:`describe` with ``baseline``, ``chosen``, ``source``,
    ``source_command``, ``source_revision`` and ``command``)."""
    baseline, chosen = meta["baseline"], meta["chosen"]
    mask_tab = _mask_tab(copycat)
    to_chosen = [
        f"## Paired differences to the chosen `{chosen}`, same seeds x tracks",
        "",
        _paired_tab(paired_chosen, chosen).to_markdown(index=False),
        "",
    ]
    lines = [
        f"# {title}",
        "",
        _intro(meta, chosen),
        "",
        _cells_tab(summary, episodes).to_markdown(index=False),
        "",
        f"## Paired differences to `{baseline}`, same seeds x tracks",
        "",
        _paired_tab(paired, baseline).to_markdown(index=False),
        "",
        *(to_chosen if chosen != baseline else []),
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
        _follow_tab(summary, copycat).to_markdown(index=False),
        "",
        f"Episodes: `{meta['source']}` ({meta['source_command']}, code "
        f"{meta['source_revision']}); tables by `{meta['command']}`; d_s from the "
        f"demonstrations, eps {meta['eps']} px.",
        "",
    ]
    return "\n".join(lines)


def describe(episodes: pd.DataFrame, config: dict[str, Any]) -> dict[str, Any]:
    """What the Markdown says about the run, from the episodes (with ``cell`` and ``view``)
    and the comparison's recorded ``config``: seeds, screen, budget, network, tracks."""
    agents = agents_of(episodes)
    per_cell = agents.groupby("cell")["train_seed"].unique()
    most = max(len(s) for s in per_cell)
    screen = sorted(c for c, s in per_cell.items() if len(s) < most)
    bcs = [m["bc"] or config["bc"] for m in config["methods"] if m.get("selection")]
    nets = ("-".join(map(str, b["network"]["channels"])) for b in bcs)
    return {
        "seeds": sorted(int(s) for s in agents["train_seed"].unique()),
        "screen_cells": screen,
        "screen_seeds": sorted({int(x) for c in screen for x in per_cell[c]}),
        "batches": " / ".join(dict.fromkeys(str(b["train"]["batches"]) for b in bcs)),
        "channels": " / ".join(dict.fromkeys(nets)),
        "episodes": int(agents["env_seed"].nunique()),
        "eval_seed": config.get("eval_seed", "?"),
        "eps": config.get("eps") or DEFAULT_EPS,
    }


def report(
    table: pd.DataFrame,
    meta: dict[str, Any],
    source: Path,
    command: str,
    *,
    episodes: Read,
    training: Read,
) -> ReportFiles:
    """The report step (:class:`~safe_bc.compare.spec.Report`): from the comparison's recorded
    configuration (``meta``: its name, title and reference, the cell the others are paired
    with), its ``episodes`` and ``training`` tables, the summary, paired, copycat and
    paired-to-chosen tables, the Markdown ``<name>.md`` and the figure ``<name>.png``;
    ``command`` is the command the Markdown names. ``table`` and ``source`` (the comparison's
    table) are not read."""
    config = meta["config"]
    name, title, baseline = config["name"], config["title"], config["reference"]
    if baseline is None:
        raise ValueError(f"comparison {name!r} names no reference to pair the cells with")
    cells = cells_and_views(episodes.frame, training.frame)
    summary, paired, copycat = summarise(cells, baseline)
    chosen = choose(summary)
    paired_chosen = paired_crossed(agents_of(cells), chosen, PAIRED_METRICS, by="cell")
    made = {
        **describe(cells, config),
        "baseline": baseline,
        "chosen": chosen,
        "bootstrap_seed": 0,
        "source": str(episodes.path),
        "source_command": episodes.meta.get("command", "?"),
        "source_revision": episodes.meta.get("git_revision", "?"),
        "inputs": episodes.meta.get("inputs", {}),
    }
    text = markdown(
        summary, paired, paired_chosen, copycat, cells, {**made, "command": command}, title
    )
    return ReportFiles(
        tables={
            "summary": summary,
            "paired": paired,
            "copycat": copycat,
            "paired_chosen": paired_chosen,
        },
        meta=made,
        texts={f"{name}.md": text},
        figures={
            f"{name}.png": Plot(
                "safe_bc.plots:plot_ablation_cells", {"summary": summary, "title": title}
            )
        },
    )
