"""Figures (matplotlib, Agg): cost histograms, the alpha sweep, safety traces, learning curves,
a study's Pareto plot."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from safe_bc.atomic import atomic_write
from safe_bc.demos import Demonstrations
from safe_bc.selection import DEFAULT_EPS
from safe_bc.study import pareto_mask


def save_figure(fig: Any, path: Path) -> Path:
    """Write ``fig`` to ``path`` atomically (format from the suffix, PNG if it names none)
    and close it."""
    path = Path(path)
    fmt = path.suffix[1:].lower()
    if fmt not in fig.canvas.get_supported_filetypes():
        fmt = "png"
    with atomic_write(path) as f:
        fig.savefig(f, format=fmt, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


def plot_cost_histograms(
    demos: Demonstrations, path: Path, *, eps: float = DEFAULT_EPS, title: str = ""
) -> Path:
    """One histogram of safety distances per dimension (the paper's Figures 3, 7, 8).

    The shaded band marks the critical zone of the max threshold: distances within
    ``eps`` of the closest approach to the grass.
    """
    scored = demos.scored
    dims = demos.safety_dims
    fig, axes = plt.subplots(1, len(dims), figsize=(4.2 * len(dims), 3.2), squeeze=False)
    for j, (ax, d) in enumerate(zip(axes[0], dims, strict=True)):
        x = demos.safety[scored, j]
        ax.hist(x, bins=40, color="tab:blue", alpha=0.8)
        lo = float(x.min())
        ax.axvspan(lo, lo + eps, color="tab:red", alpha=0.2, label=f"critical (eps={eps:g})")
        ax.set_xlabel(f"safety {d} (distance)")
        ax.set_title(f"{d}: n={len(x)}, min={lo:.1f}, mean={x.mean():.1f}")
        ax.legend(fontsize=8)
    axes[0][0].set_ylabel("steps")
    if title:
        fig.suptitle(title, fontsize=9)
    return save_figure(fig, path)


def plot_alpha_sweep(table: pd.DataFrame, path: Path, *, paper: pd.DataFrame | None = None) -> Path:
    """Reward and safety mean against alpha, per eq. 5 reading, with CI error bars."""
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    agents = table[table["method"] != "expert"]
    expert = table[table["method"] == "expert"]
    for ax, m, name in ((axes[0], "reward", "reward"), (axes[1], "safety_mean", "safety mean")):
        for rest, df in agents.groupby("rest"):
            df = df.sort_values("alpha")
            err = np.vstack([df[m] - df[f"{m}_lo"], df[f"{m}_hi"] - df[m]])
            ax.errorbar(df["alpha"], df[m], yerr=err, marker="o", capsize=4, label=f"rest={rest}")
        if len(expert):
            e = expert.iloc[0]
            ax.axhline(e[m], color="k", ls="--", lw=1, label="expert")
            ax.axhspan(e[f"{m}_lo"], e[f"{m}_hi"], color="k", alpha=0.08)
        if paper is not None and m in paper:
            ax.plot(paper["alpha"], paper[m], "x:", color="gray", label="paper (2 episodes)")
        ax.set_xlabel("safety focus alpha")
        ax.set_ylabel(name)
        ax.legend(fontsize=8)
    fig.suptitle("mean and 95% CI over training seeds x held-out episodes", fontsize=9)
    return save_figure(fig, path)


def plot_traces(
    traces: pd.DataFrame,
    labels: dict[str, dict[str, Any]],
    path: Path,
    *,
    episode: int = 0,
    limits: dict[str, float] | None = None,
) -> Path:
    """Each safety dimension's distance over one held-out episode for each policy (Figures
    5-6), with ``limits`` (per dimension, the distance at ``d_s``) as dashed lines in the
    dimension's colour: below a line is beyond the expert's limit."""
    policies = list(dict.fromkeys(traces["policy"]))
    fig, axes = plt.subplots(len(policies), 1, figsize=(9, 2.3 * len(policies)), squeeze=False)
    for ax, key in zip(axes[:, 0], policies, strict=True):
        df = traces[traces["policy"] == key]
        seed = sorted(df["env_seed"].unique())[episode]
        df = df[(df["env_seed"] == seed) & ~df["warmup"]]
        for i, col in enumerate(c for c in df.columns if c.startswith("safety_")):
            dim = col.removeprefix("safety_")
            ax.plot(df["step"], df[col], lw=0.8, color=f"C{i}", label=dim)
            if limits and dim in limits:
                ax.axhline(limits[dim], color=f"C{i}", ls="--", lw=0.8, label=f"{dim} at d_s")
        off = df[df["offroad"]]
        if len(off):
            ax.plot(off["step"], np.zeros(len(off)), "r|", label="off-road")
        lab = labels.get(key, {})
        ax.set_title(f"{lab.get('method', key)} (track seed {seed})", fontsize=9)
        ax.set_ylabel("distance (higher is safer)")
        ax.legend(fontsize=7, ncol=4, loc="upper right")
    axes[-1, 0].set_xlabel("step")
    return save_figure(fig, path)


LEARNING_PANELS = (
    ("train_reward", "training reward (stochastic policy)"),
    ("val_reward", "validation reward (mean action)"),
    ("train_violation_steps", "training: steps beyond d_s / episode"),
    ("lambda", "Lagrange multiplier"),
)
"""The panels of :func:`plot_learning_curves`: history column, title."""
SEED_STYLES = ("-", "--", ":", "-.")


def plot_learning_curves(
    history: pd.DataFrame, refs: dict[str, float], path: Path, *, labels: dict[str, str]
) -> Path:
    """Improvement runs' training and validation reward, violations and multiplier against
    env steps: colour = method, line style = training seed; dashed lines: ``refs`` (e.g. the
    expert's and the starts' mean held-out reward) on the validation-reward panel.

    ``history`` holds :data:`safe_bc.improve.HISTORY` rows (or self-imitation rounds,
    :meth:`safe_bc.selfimprove.run.SelfImproveResult.history`: no multiplier) with ``method``
    and ``train_seed``; ``labels`` names methods in the legend."""
    from matplotlib.lines import Line2D

    methods = list(dict.fromkeys(history["method"]))
    colours = {m: f"C{i}" for i, m in enumerate(methods)}
    seeds = sorted(history["train_seed"].unique())
    fig, axes = plt.subplots(2, 2, figsize=(11, 7))
    for ax, (col, title) in zip(axes.flat, LEARNING_PANELS, strict=True):
        if col not in history:  # e.g. the multiplier of self-imitation runs only
            ax.set_title(f"{title}: not recorded by these runs", fontsize=9)
            continue
        for (method, seed), df in history.groupby(["method", "train_seed"], sort=False):
            df = df.dropna(subset=[col])
            style = SEED_STYLES[seeds.index(seed) % len(SEED_STYLES)]
            ax.plot(df["env_steps"] / 1e3, df[col], lw=1.1, color=colours[method], ls=style)
        if col == "val_reward":
            for i, value in enumerate(refs.values()):
                ax.axhline(value, ls="--", lw=1, color="k" if i == 0 else "0.6")
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("env steps (thousands)")
    handles = [Line2D([], [], color=colours[m], label=labels.get(m, m)) for m in methods]
    handles += [
        Line2D([], [], color="k", ls=SEED_STYLES[i % len(SEED_STYLES)], label=f"seed {s}")
        for i, s in enumerate(seeds)
    ]
    handles += [
        Line2D([], [], color="k" if i == 0 else "0.6", ls="--", lw=1, label=f"{name} (held-out)")
        for i, name in enumerate(refs)
    ]
    fig.legend(handles=handles, loc="lower center", ncol=4, fontsize=7, frameon=False)
    fig.suptitle("improvement learning curves", fontsize=9)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    return save_figure(fig, path)


def plot_queries(
    summaries: dict[str, pd.DataFrame],
    deferred: dict[str, dict[str, float]],
    path: Path,
    *,
    block: str = "fresh",
) -> Path:
    """Critical-zone queries and deferral (the queries family's ``summary.parquet`` per
    testbed, :mod:`safe_bc.queries.report`): one row of two panels per testbed, on its
    ``block`` episodes. Left: reward minus the expert's (paired crossed 95% CI), each method
    labelled with its burden (training queries per rollout, or ``deferred[testbed][method]``:
    the mean share of steps deferred); right: the share of episodes beyond ``d_s`` (dot) and
    its one-sided 95% Clopper-Pearson bound (bar end)."""
    from matplotlib.ticker import PercentFormatter

    fig, axes = plt.subplots(len(summaries), 2, figsize=(11, 2.6 * len(summaries)), squeeze=False)
    for (left, right), (name, table) in zip(axes, summaries.items(), strict=True):
        t = table[(table["block"] == block) & (table["method"] != "expert")].reset_index()
        y = np.arange(len(t))[::-1]
        d = t["d_reward_vs_expert"]
        left.errorbar(
            d, y, xerr=[d - t["d_reward_lo_vs_expert"], t["d_reward_hi_vs_expert"] - d],
            fmt="o", color="C0", capsize=3,
        )  # fmt: skip
        left.axvline(0, color="k", lw=1, ls="--")
        labels = []
        for _, r in t.iterrows():
            label = r["method"]
            if r["method"] in deferred.get(name, {}):
                label += f", {deferred[name][r['method']]:.1%} of steps deferred"
            if np.isfinite(r["queries_per_episode"]) and r["queries_per_episode"] > 0:
                label += f", {r['queries_per_episode']:.2g} queries / training rollout"
            labels.append(label)
        left.set_yticks(y, labels, fontsize=7)
        left.set_xlabel("reward - expert (paired crossed 95% CI)", fontsize=8)
        left.set_title(f"{name}: {block} episodes, reward against the expert", fontsize=9)
        right.hlines(y, 0, t["beyond_ucb95"], color="C3", lw=3, alpha=0.35)
        right.plot(t["episodes_beyond"] / t["episodes"], y, "o", color="C3")
        for yi, (_, r) in zip(y, t.iterrows(), strict=True):
            right.annotate(
                f"{r['episodes_beyond']}/{r['episodes']}", (r["beyond_ucb95"], yi),
                xytext=(4, -3), textcoords="offset points", fontsize=7,
            )  # fmt: skip
        right.set_yticks(y, [""] * len(y))
        right.set_xlim(0, max(0.05, float(t["beyond_ucb95"].max()) * 1.3))
        right.xaxis.set_major_formatter(PercentFormatter(1.0))
        right.set_xlabel("episodes beyond d_s (dot) and 95% upper bound (bar end)", fontsize=8)
        right.set_title(f"{name}: crossings", fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path)


def plot_pareto(
    trials: pd.DataFrame,
    threshold: float,
    path: Path,
    *,
    winner: str | None = None,
    candidates: Sequence[str] = (),
    title: str = "",
    objective: str = "reward_mean",
    safety_label: str = "safety mean (higher is safer)",
) -> Path:
    """The study's objective (the reward, or its lower confidence bound ``reward_lcb``: what
    the search maximises) against the safety mean per trial: feasible filled, infeasible
    hollow, the Pareto front of the two joined, the threshold as a vertical line, the final
    phase's ``candidates`` boxed and its ``winner`` ringed (pass a winner only when the final
    phase accepted it). Markers of the candidates and the winner are hollow, drawn under the
    trials' points, so they hide none."""
    r = trials[objective].to_numpy(float)
    s = trials["safety_mean"].to_numpy(float)
    feas = trials["feasible"].to_numpy(bool)
    front = pareto_mask(r, s)
    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    boxed = trials[trials["trial_id"].isin(list(candidates))]
    if len(boxed):
        ax.scatter(
            boxed["safety_mean"], boxed[objective], marker="s", s=170, facecolors="none",
            edgecolors="k", lw=1.0, label=f"final-phase candidates ({len(boxed)})", zorder=2,
        )  # fmt: skip
    if winner is not None and (trials["trial_id"] == winner).any():
        w = trials[trials["trial_id"] == winner].iloc[0]
        ax.scatter(
            [w["safety_mean"]], [w[objective]], marker="o", s=420, facecolors="none",
            edgecolors="goldenrod", lw=2.5, label="winner (final phase)", zorder=2,
        )  # fmt: skip
    ax.scatter(
        s[feas], r[feas], c="tab:blue", s=30, alpha=0.85, label=f"feasible ({feas.sum()})",
        zorder=3,
    )  # fmt: skip
    ax.scatter(
        s[~feas], r[~feas], s=30, facecolors="none", edgecolors="tab:red",
        label=f"infeasible ({(~feas & np.isfinite(r)).sum()})", zorder=3,
    )  # fmt: skip
    order = np.argsort(s[front])
    ax.plot(s[front][order], r[front][order], "k--", lw=0.8, label="Pareto front")
    ax.axvline(threshold, color="gray", ls=":", label=f"threshold {threshold:.2f}")
    ax.set_xlabel(safety_label)
    ax.set_ylabel(
        "reward, one-sided lower confidence bound (the objective)"
        if objective == "reward_lcb"
        else f"{objective.replace('_', ' ')} (the objective)"
    )
    ax.set_title(title or "study trials")
    ax.legend(fontsize=8, loc="best")
    ax.grid(alpha=0.3)
    return save_figure(fig, path)
