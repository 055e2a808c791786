"""Figures (matplotlib, Agg): cost histograms, the alpha sweep, safety traces, learning curves,
a study's Pareto plot, the observation ablation's cells."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from safe_bc.data.atomic import atomic_write
from safe_bc.data.demos import Demonstrations
from safe_bc.metrics import pareto_mask
from safe_bc.selection import DEFAULT_EPS


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


COST_UNITS = "cost units"
"""The unit of a safety dimension whose task names none (``TaskSpec.safety_units``)."""


def unit_of(units: Sequence[str], j: int) -> str:
    """The unit of safety dimension ``j`` (:data:`COST_UNITS` where ``units`` names none)."""
    return units[j] if j < len(units) and units[j] else COST_UNITS


def safety_mean_label(units: Sequence[str]) -> tuple[str, str]:
    """The safety mean's axis label and a note for the panel: the mean of each step's
    smallest distance, in the dimensions' unit; where their units differ, the label says so
    and the note names them."""
    names = list(dict.fromkeys(unit_of(units, j) for j in range(max(len(units), 1))))
    if len(names) == 1:
        return f"safety mean ({names[0]}, higher is safer)", ""
    return (
        "safety mean (mixed units, higher is safer)",
        f"each step's smallest margin, in its dimension's unit ({', '.join(names)})",
    )


def plot_cost_histograms(
    demos: Demonstrations,
    path: Path,
    *,
    eps: float = DEFAULT_EPS,
    title: str = "",
    units: Sequence[str] = (),
) -> Path:
    """One histogram of safety distances per dimension (the paper's Figures 3, 7, 8).

    The solid red line is the distance at ``d_s`` (the closest scored approach: ``d_s`` is
    the largest cost); the shaded band is the critical zone, distances within ``eps`` of it.
    ``units``: per dimension, the distance's unit (``TaskSpec.safety_units``).
    """
    scored = demos.scored
    dims = demos.safety_dims
    episodes = len(set(demos.episode_ids.tolist()))
    fig, axes = plt.subplots(
        1, len(dims), figsize=(4.4 * len(dims), 3.6), squeeze=False, layout="constrained"
    )
    for j, (ax, d) in enumerate(zip(axes[0], dims, strict=True)):
        unit = unit_of(units, j)
        x = demos.safety[scored, j]
        ax.hist(x, bins=40, color="tab:blue", alpha=0.8)
        lo = float(x.min())
        ax.axvspan(
            lo, lo + eps, color="tab:red", alpha=0.2, label=f"critical zone (eps {eps:g} {unit})"
        )
        ax.axvline(lo, color="tab:red", lw=1.2, label=f"at d_s: {lo:.3g} {unit}")
        ax.set_xlabel(f"{d}: distance ({unit}), higher is safer")
        ax.set_title(f"{d}: mean {x.mean():.3g} {unit}", fontsize=9)
        ax.legend(fontsize=7)
    axes[0][0].set_ylabel("scored steps")
    caption = (
        f"{episodes} demonstration episodes, {int(scored.sum())} scored steps; d_s: the "
        "largest cost, at the closest scored approach"
    )
    fig.suptitle(f"{title}\n{caption}" if title else caption, fontsize=9)
    return save_figure(fig, path)


def seeds_by_episodes(rows: pd.DataFrame) -> str:
    """``N training seeds x M held-out episodes`` of a table's rows (their ``n_train_seeds``
    and ``n_tracks``; values that differ between rows joined by ``/``); empty where the table
    has no such columns."""
    if rows.empty or not {"n_train_seeds", "n_tracks"} <= set(rows.columns):
        return ""

    def values(col: str) -> str:
        return "/".join(str(int(v)) for v in sorted(set(rows[col].dropna())))

    return f"{values('n_train_seeds')} training seeds x {values('n_tracks')} held-out episodes"


def plot_alpha_sweep(
    table: pd.DataFrame,
    path: Path,
    *,
    paper: pd.DataFrame | None = None,
    units: Sequence[str] = (),
) -> Path:
    """Reward and safety mean against alpha, per eq. 5 reading, with CI error bars; the title
    says how many training seeds x held-out episodes each point is a mean over (read from
    the table's ``n_train_seeds`` and ``n_tracks``)."""
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.0), layout="constrained")
    agents = table[table["method"] != "expert"]
    expert = table[table["method"] == "expert"]
    safety, note = safety_mean_label(units)
    panels = (
        (axes[0], "reward", "reward (episode return)", ""),
        (axes[1], "safety_mean", safety, note),
    )
    for ax, m, name, note in panels:
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
        ax.set_title(note, fontsize=8)
        ax.legend(fontsize=8)
    budget = seeds_by_episodes(agents)
    title = "mean and 95% CI over " + (budget or "training seeds x held-out episodes")
    if budget and len(expert) and "n_tracks" in expert:
        title += f" (expert: {int(expert['n_tracks'].iloc[0])} episodes)"
    fig.suptitle(title, fontsize=9)
    return save_figure(fig, path)


def plot_traces(
    traces: pd.DataFrame,
    labels: dict[str, dict[str, Any]],
    path: Path,
    *,
    episode: int = 0,
    limits: dict[str, float] | None = None,
    units: dict[str, str] | None = None,
) -> Path:
    """Each safety dimension's distance over one held-out episode for each policy (Figures
    5-6), with ``limits`` (per dimension, the distance at ``d_s``) as dashed lines in the
    dimension's colour: below a line is beyond the expert's limit. ``units``: per dimension,
    the distance's unit (:data:`COST_UNITS` where it names none). One legend for all panels, below
    them; a panel's title names its policy (the table's policy key where it extends the
    ``method`` label, e.g. with the training seed) and its track."""
    policies = list(dict.fromkeys(traces["policy"]))
    fig, axes = plt.subplots(
        len(policies), 1, figsize=(9, 2.3 * len(policies) + 0.9), squeeze=False, sharex=True,
        layout="constrained",
    )  # fmt: skip
    columns = [c for c in traces.columns if c.startswith("safety_")]
    dims = [c.removeprefix("safety_") for c in columns]
    unit = {d: (units or {}).get(d) or COST_UNITS for d in dims}
    shown = set(unit.values())
    handles: dict[str, Any] = {}
    for ax, key in zip(axes[:, 0], policies, strict=True):
        df = traces[traces["policy"] == key]
        seed = sorted(df["env_seed"].unique())[episode]
        df = df[(df["env_seed"] == seed) & ~df["warmup"]]
        for i, col in enumerate(columns):
            dim = col.removeprefix("safety_")
            ax.plot(df["step"], df[col], lw=0.8, color=f"C{i}", label=f"{dim} ({unit[dim]})")
            if limits and dim in limits:
                ax.axhline(
                    limits[dim], color=f"C{i}", ls="--", lw=0.8,
                    label=f"{dim} at d_s ({limits[dim]:.3g} {unit[dim]})",
                )  # fmt: skip
        off = df[df["offroad"]]
        if len(off):
            ax.plot(off["step"], np.zeros(len(off)), "r|", label="off-road")
        method = labels.get(key, {}).get("method", key)
        name = key if key.startswith(method) else method
        ax.set_title(f"{name}, episode seed {seed}", fontsize=9)
        ax.set_ylabel(f"distance ({next(iter(shown))})" if len(shown) == 1 else "distance")
        for h, label in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(label, h)
    axes[-1, 0].set_xlabel("step")
    fig.legend(
        handles.values(), handles.keys(), loc="outside lower center", ncol=max(len(columns), 1),
        fontsize=7, frameon=False,
    )  # fmt: skip
    fig.suptitle(
        "safety distance over one held-out episode per policy (higher is safer; dashed: the "
        "distance at d_s, below it is beyond the expert's limit)",
        fontsize=9,
    )
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

    ``history`` holds :data:`safe_bc.methods.improve.HISTORY` rows (or self-imitation rounds,
    :meth:`safe_bc.methods.selfimprove.run.SelfImproveResult.history`: no multiplier) with
    ``method``
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
    testbed, ``scripts/queries_report.py``): one row of two panels per testbed, on its
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


def trial_budgets(trials: pd.DataFrame) -> str:
    """How many training seeds x episodes each trial was evaluated on (the trial table's
    ``train_seeds`` and ``episodes``), one group per budget, the largest first; empty where
    the table has no such columns."""
    if not {"train_seeds", "episodes"} <= set(trials.columns):
        return ""
    done = trials.dropna(subset=["train_seeds", "episodes"])
    groups = []
    for (seeds, episodes), df in done.groupby(["train_seeds", "episodes"]):
        early = "status" in df and (df["status"] == "stopped").all()
        groups.append(
            (int(episodes), f"{len(df)} trials of {int(seeds)} training seed"
             f"{'s' if seeds != 1 else ''} x {int(episodes)} episodes"
             + (" (stopped early)" if early else ""))
        )  # fmt: skip
    return "; ".join(text for _, text in sorted(groups, reverse=True))


def objective_label(objective: str) -> str:
    """The name of what the y axis of :func:`plot_pareto` plots."""
    if objective == "reward_lcb":
        return "reward_lcb: the reward's one-sided lower\nconfidence bound (the objective)"
    return f"{objective} (the objective)"


def _zoom_box(points: np.ndarray) -> tuple[float, float, float, float]:
    """``(x0, x1, y0, y1)`` around ``points`` ``(n, 2)`` with a margin of a third of their
    spread on each side (1% of the value where they do not spread)."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    pad = np.where(hi > lo, (hi - lo) / 3, 0.01 * np.abs(hi) + 1e-9)
    return lo[0] - pad[0], hi[0] + pad[0], lo[1] - pad[1], hi[1] + pad[1]


def _label_trials(ax: Any, trials: pd.DataFrame, objective: str, marked: Sequence[str]) -> None:
    """Each trial's id beside its point (trials at the same point in one label); the
    ``marked`` ones (candidates, winner) in black above their markers, the others in grey
    below their points."""
    at: dict[tuple[float, float], list[str]] = {}
    for tid, x, y in zip(trials["trial_id"], trials["safety_mean"], trials[objective], strict=True):
        if np.isfinite(x) and np.isfinite(y):
            at.setdefault((float(x), float(y)), []).append(str(tid)[:8])
    for (x, y), ids in at.items():
        key = any(i in marked for i in ids)
        ax.annotate(
            " = ".join(ids), (x, y), xytext=(9, 9) if key else (5, -11),
            textcoords="offset points", fontsize=7 if key else 6,
            color="k" if key else "0.4", annotation_clip=True,
        )  # fmt: skip


def _draw_trials(ax: Any, trials: pd.DataFrame, threshold: float, objective: str) -> None:
    """One panel of :func:`plot_pareto`: feasible trials filled, infeasible hollow, the front
    dashed, the threshold dotted."""
    r = trials[objective].to_numpy(float)
    s = trials["safety_mean"].to_numpy(float)
    feas = trials["feasible"].to_numpy(bool)
    front = pareto_mask(r, s)
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
    ax.axvline(threshold, color="gray", ls=":", label=f"threshold {threshold:.3g}")


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
    trials' points, so they hide none.

    With candidates or a winner, a second panel zooms in on them (the grey box on the first),
    every trial there labelled with its id: they sit within a few reward points of each
    other. The title's second line says how many seeds x episodes each trial was evaluated
    on (:func:`trial_budgets`)."""
    boxed = trials[trials["trial_id"].isin(list(candidates))]
    chosen = trials[trials["trial_id"] == winner] if winner is not None else trials.iloc[:0]
    marked = pd.concat([boxed, chosen])
    panels = 2 if len(marked) else 1
    fig, axes = plt.subplots(
        1, panels, figsize=(6.4 * panels, 5.0), squeeze=False, layout="constrained"
    )
    for ax in axes[0]:
        _draw_trials(ax, trials, threshold, objective)
        if len(boxed):
            ax.scatter(
                boxed["safety_mean"], boxed[objective], marker="s", s=170, facecolors="none",
                edgecolors="k", lw=1.0, label=f"final-phase candidates ({len(boxed)})",
                zorder=2,
            )  # fmt: skip
        if len(chosen):
            w = chosen.iloc[0]
            ax.scatter(
                [w["safety_mean"]], [w[objective]], marker="o", s=420, facecolors="none",
                edgecolors="goldenrod", lw=2.5, label=f"winner {str(w['trial_id'])[:8]}",
                zorder=2,
            )  # fmt: skip
        ax.set_xlabel(safety_label)
        ax.set_ylabel(objective_label(objective))
        ax.grid(alpha=0.3)
    if panels == 2:
        x0, x1, y0, y1 = _zoom_box(marked[["safety_mean", objective]].to_numpy(float))
        axes[0][1].set_xlim(x0, x1)
        axes[0][1].set_ylim(y0, y1)
        axes[0][1].set_title("zoom on the final phase's candidates", fontsize=9)
        _label_trials(axes[0][1], trials, objective, list(marked["trial_id"]))
        axes[0][0].add_patch(
            plt.Rectangle((x0, y0), x1 - x0, y1 - y0, fc="0.5", alpha=0.25, ec="0.3", zorder=1)
        )
    handles, names = axes[0][0].get_legend_handles_labels()
    fig.legend(
        handles, names, loc="outside lower center", ncol=min(len(names), 4), fontsize=8,
        frameon=False,
    )  # fmt: skip
    budgets = trial_budgets(trials)
    fig.suptitle((title or "study trials") + (f"\n{budgets}" if budgets else ""), fontsize=10)
    return save_figure(fig, path)


def plot_ablation_cells(summary: pd.DataFrame, path: Path, *, title: str) -> Path:
    """The observation ablation's cells (the summary of
    :func:`safe_bc.compare.observation_choice.summarise`: one row per ``cell`` and ``view``):
    reward and share of episodes beyond d_s with their CIs on the full frame (a filled marker
    where the cell has every training seed, open where it is a screen), the steering-masked
    view's mean, the expert's as a line."""
    full = summary[(summary["view"] == "full") & (summary["cell"] != "expert")]
    full = full.sort_values("reward")
    masked = summary[summary["view"] == "steer_masked"].set_index("cell")
    expert = summary[summary["cell"] == "expert"]
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
        if len(expert):
            ax.axvline(expert.iloc[0][m], color="k", ls="--", lw=1, label="expert")
        ax.set_title(panel)
        ax.grid(alpha=0.3)
    axes[0].set_yticks(y, full["cell"])
    axes[0].legend(loc="lower right", fontsize=8)
    fig.suptitle(f"{title}: seeds x selection tracks, 95% crossed CIs")
    return save_figure(fig, path)
