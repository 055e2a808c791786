"""Table 1 of the paper, rerun honestly: an alpha sweep and peer baselines x training seeds.

Every method's agents (one per training seed, the seeds shared across methods) and the
expert are evaluated on the same held-out tracks. Rows (``ReproduceConfig.methods``): the
alpha mix for each ``alpha`` (``alpha = 0``, ``rest="all"`` is plain BC; ``alpha = 1`` is BC on
``T_eps`` only), OSRL's BC-Safe and cost-weighted BC (``SelectionConfig.mode``), the expert.

Writes under ``out`` (default ``results/``):

* ``table1.parquet``: one row per method with means and 95% crossed bootstrap CIs over
  training seeds and tracks (:func:`safe_bc.metrics.summarize_crossed`), paired differences
  to plain BC on the same (seed, track) cells and how many seeds beat plain BC; metadata
  records the command, seeds, configs and code revision.
* ``table1.md``: the same as Markdown, beside the paper's numbers.
* ``table1_episodes.parquet``: one row per evaluated episode.
* ``table1_selection.parquet``: which demonstrations were critical (thresholds in metadata).
* ``fig4_alpha.png``: reward and safety against alpha with CI error bars.
* ``fig5_6_traces.png``: safety traces of alpha 0 and alpha 0.8 agents and the expert.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, get_args

import numpy as np
import pandas as pd

from safe_bc.atomic import write_text_atomic
from safe_bc.bc import BCConfig
from safe_bc.collection import stored_expert_config
from safe_bc.data.store import load_demonstrations, write_table_atomic
from safe_bc.envs import EnvConfig
from safe_bc.evaluation import EvalConfig, ExpertSource, NetSource
from safe_bc.experiment import RunConfig, save_selection, select_for
from safe_bc.metrics import METRICS, combined, paired_crossed, summarize_crossed
from safe_bc.provenance import run_metadata
from safe_bc.report import fmt_ci, markdown_table
from safe_bc.selection import RULES, Baseline, Rest, SelectionConfig
from safe_bc.tasks import Task, dataset_action_bounds, task_defaults, task_of

Reading = Rest

PAPER_TABLE1 = pd.DataFrame(
    {
        "alpha": [0.0, 0.1, 0.5, 0.8],
        "safety_mean": [13.05, 17.30, 21.37, 20.94],
        "safety_std": [16.41, 12.87, 11.12, 14.08],
        "reward": [139.50, 228.88, 697.41, 549.51],
    }
)
"""Boecking & Philipp (2020), Table 1 (2 evaluation episodes, one training run each)."""

PAIRED_METRICS = ("reward", "safety_mean", "violation_steps")
"""Metrics paired with plain BC on the same (seed, track) cells (those present)."""

PLAIN_BC = "alpha=0 (rest=all)"
"""Row label of plain behaviour cloning, the reference of the paired columns."""


@dataclass(frozen=True)
class Method:
    """One row of Table 1: its label and the selection rule its agents train with."""

    name: str
    """Row label, e.g. ``alpha=0.5 (rest=all)`` or ``BC-Safe (K=20)``."""
    selection: SelectionConfig
    """``T_eps`` and the training rule (``mode``) of the row's agents."""

    @property
    def labels(self) -> dict[str, Any]:
        """Columns that identify the row in the episodes table."""
        mix = self.selection.mode == "mix"
        return {
            "method": self.name,
            "mode": self.selection.mode,
            "alpha": self.selection.alpha if mix else float("nan"),
            "rest": self.selection.rest if mix else "",
        }


@dataclass(frozen=True)
class ReproduceConfig:
    """The Table 1 rerun: which rows, how many training seeds and held-out tracks."""

    demos: Path = Path("data/demos")
    """Demonstration dataset (built with the default collection if absent)."""
    out: Path = Path("results")
    """Where tables and figures go."""
    alphas: tuple[float, ...] = (0.0, 0.1, 0.5, 0.8, 1.0)
    """Safety focus values of the alpha-mix rows: the paper's four and 1.0 (BC on ``T_eps``
    only). With ``rest="all"``, alpha = 0 is plain BC, the paired columns' reference."""
    eps: float | None = None
    """Critical-zone width in the cost's units; ``None``: the task's (2 px for CarRacing,
    where the paper's 5 px puts 95% of the default demonstrations in ``T_eps``; 0.05 for
    rehab)."""
    readings: tuple[Reading, ...] = ("all",)
    """Readings of eq. 5 for the alpha rows: the rest drawn from all of T (the text; the
    default) and, opt-in, from ``T \\ T_eps`` (``"noncritical"``). ``alpha = 1`` is the same
    under both, so it is trained once, under ``"all"``, when both are asked for."""
    baselines: tuple[Baseline, ...] = get_args(Baseline)
    """Peer baselines as extra rows: OSRL's BC-Safe and cost-weighted BC
    (``SelectionConfig.mode``)."""
    segment_steps: int = SelectionConfig.segment_steps
    """BC-Safe's segment length K in scored steps (``SelectionConfig.segment_steps``)."""
    beta: float = SelectionConfig.beta
    """Cost-weighted BC's strength (``SelectionConfig.beta``)."""
    train_seeds: tuple[int, ...] = tuple(range(8))
    """Training seeds, shared by every method (one agent per method and seed)."""
    episodes: int = 20
    """Held-out tracks, the same for every agent and the expert (one episode each)."""
    eval_seed: int = 0
    """Block of held-out track seeds."""
    workers: int = 2
    """Evaluation actors."""
    bc: BCConfig = field(default_factory=BCConfig)
    """Network, preprocessing and training budget (2000 batches by default)."""
    max_steps: int | None = None
    """Step cap of evaluation episodes (``None``: the full 1000)."""
    task: Task = "carracing"
    """The testbed: ``carracing`` or ``rehab`` (its env, expert and default collection)."""

    def __post_init__(self) -> None:
        for a in self.alphas:
            if not 0.0 <= a <= 1.0:
                raise ValueError(f"alpha must be in [0, 1], got {a}")
        if len(set(self.alphas)) != len(self.alphas):
            raise ValueError(f"alphas repeat a value: {self.alphas}")
        if self.eps is not None and not (math.isfinite(self.eps) and self.eps >= 0):
            raise ValueError(f"eps must be a finite number >= 0, got {self.eps}")
        if not self.readings or len(set(self.readings)) != len(self.readings):
            raise ValueError(f"readings must be distinct and not empty, got {self.readings}")
        for r in self.readings:
            if r not in get_args(Reading):
                raise ValueError(f"reading must be one of {get_args(Reading)}, got {r!r}")
        for b in self.baselines:
            if b not in get_args(Baseline):
                raise ValueError(f"baseline must be one of {get_args(Baseline)}, got {b!r}")
        if len(set(self.baselines)) != len(self.baselines):
            raise ValueError(f"baselines repeat a value: {self.baselines}")
        if not self.train_seeds:
            raise ValueError("need at least one training seed")
        if len(set(self.train_seeds)) != len(self.train_seeds):
            raise ValueError(f"train_seeds repeat a value: {self.train_seeds}")
        if self.episodes < 1:
            raise ValueError(f"episodes must be >= 1, got {self.episodes}")
        if not self.methods():
            raise ValueError("no method to train: give alphas or baselines")

    @property
    def env(self) -> EnvConfig:
        """The task's environment."""
        return task_defaults(self.task).env

    @property
    def selection_eps(self) -> float:
        """``eps``, or the task's default."""
        return task_defaults(self.task).eps if self.eps is None else self.eps

    def methods(self) -> list[Method]:
        """The trained rows, in table order: the alpha mix per reading, then the baselines.

        Raises:
            ValueError: ``segment_steps`` or ``beta`` out of range.
        """
        eps = self.selection_eps
        rows = [
            Method(method_name(a, r), SelectionConfig(eps=eps, alpha=a, rest=r))
            for r in self.readings
            for a in self.alphas
            if not (a == 1.0 and r == "noncritical" and "all" in self.readings)
        ]
        for b in self.baselines:
            cfg = SelectionConfig(
                eps=eps, alpha=0.0, mode=b, segment_steps=self.segment_steps, beta=self.beta
            )
            rows.append(Method(baseline_name(cfg), cfg))
        return rows


def method_name(alpha: float, reading: Rest) -> str:
    """Row label of an alpha-mix configuration, e.g. ``alpha=0.5 (rest=all)``."""
    return RULES["mix"].label(SelectionConfig(alpha=alpha, rest=reading))


def baseline_name(config: SelectionConfig) -> str:
    """Row label of a peer baseline, e.g. ``BC-Safe (K=20)``, ``cost-weighted BC (beta=9)``."""
    return RULES[config.mode].label(config)


def run_reproduce(config: ReproduceConfig, *, progress: bool = True) -> pd.DataFrame:
    """Train every (method, seed), evaluate them and the expert on the same tracks, write
    the results."""
    from safe_bc.distributed.collect import ensure_demos
    from safe_bc.distributed.evaluate import LOCKSTEP_ENVS, evaluate_policies
    from safe_bc.distributed.train import train_many

    started = time.perf_counter()
    ensure_demos(config.demos, task_defaults(config.task).collect_config(), progress=progress)
    demos = load_demonstrations(config.demos)
    meta = _metadata(config)
    config.out.mkdir(parents=True, exist_ok=True)

    eps = config.selection_eps
    base = select_for(demos, SelectionConfig(eps=eps, alpha=0.0))
    save_selection(config.out / "table1_selection", demos, base, meta)

    bounds = dataset_action_bounds(config.demos)
    methods = config.methods()
    for method in methods:  # fail fast, before any training, on an impossible mix or rule
        select_for(demos, method.selection).sampler(
            config.bc.train.batch_size, np.random.default_rng(0)
        )
    runs = [(m, s) for m in methods for s in config.train_seeds]
    run_cfgs = [
        RunConfig(
            m.selection,
            dataclasses.replace(config.bc, train=dataclasses.replace(config.bc.train, seed=seed)),
        )
        for m, seed in runs
    ]
    trained = train_many(
        demos, run_cfgs, workers=config.workers, action_bounds=bounds, progress=progress
    )
    sources: dict[str, Any] = {}
    labels: dict[str, dict[str, Any]] = {}
    train_rows = []
    for (method, seed), (result, selection) in zip(runs, trained, strict=True):
        key = f"{method.name} seed={seed}"
        sources[key] = NetSource.from_model(result.model, result.config)
        labels[key] = {**method.labels, "train_seed": seed}
        train_rows.append(
            {
                **labels[key],
                "final_loss": result.final_loss,
                "samples_per_s": result.samples_per_s,
                "n_critical": selection.n_critical,
                "n_train_rows": selection.n_train_rows,
                "critical_sample_share": selection.critical_sample_share,
            }
        )
    sources["expert"] = ExpertSource(stored_expert_config(config.demos))
    labels["expert"] = {
        "method": "expert",
        "mode": "expert",
        "alpha": np.nan,
        "rest": "",
        "train_seed": 0,
    }

    eval_cfg = EvalConfig(
        episodes=config.episodes,
        workers=config.workers,
        seed=config.eval_seed,
        env=config.env,
        max_steps=config.max_steps,
        eps=eps,
    )
    episodes, steps = evaluate_policies(
        sources,
        eval_cfg,
        thresholds=base.thresholds,
        progress=progress,
        envs_per_worker=LOCKSTEP_ENVS,
    )
    label_df = pd.DataFrame.from_dict(labels, orient="index").rename_axis("policy").reset_index()
    episodes = label_df.merge(episodes, on="policy")
    train_df = pd.DataFrame(train_rows)
    meta["seconds"] = round(time.perf_counter() - started, 1)
    meta["demo_safety_mean"] = float(combined(demos.safety[demos.scored]).mean())
    traces = steps[steps["policy"].isin(_trace_policies(labels))]
    write_table_atomic(config.out / "table1_episodes.parquet", episodes, meta)
    write_table_atomic(config.out / "table1_traces.parquet", traces, meta)
    write_table_atomic(config.out / "table1_training.parquet", train_df, meta)
    return write_outputs(config, episodes, traces, train_df, meta)


def summary_metrics(episodes: pd.DataFrame) -> list[str]:
    """The metrics of :data:`safe_bc.metrics.METRICS` the episodes table holds (violation
    metrics only where the evaluation produced them), in that order."""
    return [m for m in METRICS if m in episodes and episodes[m].notna().any()]


def table1(
    config: ReproduceConfig, episodes: pd.DataFrame, train_df: pd.DataFrame | None = None
) -> pd.DataFrame:
    """Table 1 from per-episode results (one row per method, in ``config``'s order).

    Per method: every metric of :func:`summary_metrics` as a mean over its (training seed,
    track) cells with a 95% crossed bootstrap CI (:func:`safe_bc.metrics.summarize_crossed`:
    seeds and tracks resampled independently, because every agent ran on the same tracks;
    the nested seeds-then-episodes bootstrap would ignore that and under-cover with few
    seeds), ``n_train_seeds``, ``n_tracks``, ``episodes_with_violation``; against plain BC
    (``alpha=0 (rest=all)``, when it is a row) the paired differences ``d_<metric>`` on the
    same cells with the same bootstrap, and ``seeds_better`` of ``n_seeds_paired`` training
    seeds whose mean reward over the tracks beats plain BC's same seed. With ``train_df``,
    the training means (loss, throughput, critical share of the batches) per method.
    """
    episodes = _with_mode(episodes)
    metrics = summary_metrics(episodes)
    table = summarize_crossed(episodes, ["method"], metrics)
    ids = episodes[["method", "mode", "alpha", "rest"]].drop_duplicates("method")
    table = ids.merge(table, on="method", how="right")
    if "any_violation" in metrics:
        counts = episodes.groupby("method")["any_violation"].sum().astype(int)
        table["episodes_with_violation"] = table["method"].map(counts)
    if PLAIN_BC in set(episodes["method"]):
        agents = episodes[episodes["method"] != "expert"]  # trained once: no seed pairing
        paired = [m for m in PAIRED_METRICS if m in metrics]
        diffs = paired_crossed(agents, PLAIN_BC, paired, better="reward")
        if len(diffs):
            table = table.merge(diffs, on="method", how="left")
    table = _order(table, config)
    if train_df is not None and len(train_df):
        cols = [
            c for c in ("final_loss", "samples_per_s", "critical_sample_share") if c in train_df
        ]
        table = table.merge(
            train_df.groupby("method")[cols].mean().reset_index(), on="method", how="left"
        )
    return table


def write_outputs(
    config: ReproduceConfig,
    episodes: pd.DataFrame,
    traces: pd.DataFrame,
    train_df: pd.DataFrame,
    meta: dict[str, Any],
) -> pd.DataFrame:
    """Summarise per-episode results into Table 1, its Markdown and the figures."""
    table = table1(config, episodes, train_df)
    write_table_atomic(config.out / "table1.parquet", table, meta)
    paper_table1 = task_defaults(config.task).paper_table1
    markdown = render_markdown(table, meta, paper=paper_table1)
    write_text_atomic(config.out / "table1.md", markdown)
    from safe_bc.plots import plot_alpha_sweep, plot_traces

    paper = PAPER_TABLE1 if paper_table1 else None
    sweep = table[table["mode"].isin(["mix", "expert"])]  # the baselines have no alpha
    plot_alpha_sweep(sweep, config.out / "fig4_alpha.png", paper=paper)
    labels = {p: {"method": m} for p, m in episodes[["policy", "method"]].drop_duplicates().values}
    if len(traces):
        plot_traces(traces, labels, config.out / "fig5_6_traces.png")
    return table


def rerender(config: ReproduceConfig) -> pd.DataFrame:
    """Rebuild Table 1, its Markdown and figures from the stored per-episode results.

    Nothing is trained or evaluated again; the metadata keeps the original run's
    command and revision and adds the re-rendering's under ``rendered``. Rows and their order
    come from the stored configuration (runs before the peer baselines had none).
    """
    from safe_bc.data.store import read_table

    episodes, meta = read_table(config.out / "table1_episodes.parquet")
    traces, _ = read_table(config.out / "table1_traces.parquet")
    training = config.out / "table1_training.parquet"
    if training.exists():
        train_df, _ = read_table(training)
    else:  # runs before the training table existed kept these columns in table1.parquet
        old, _ = read_table(config.out / "table1.parquet")
        train_df = old[["method", "final_loss", "samples_per_s"]].dropna()
    meta = {**meta, "rendered": run_metadata()}
    stored = meta.get("config", {})
    config = dataclasses.replace(
        config,
        alphas=tuple(stored.get("alphas", config.alphas)),
        readings=tuple(stored.get("readings", config.readings)),
        baselines=tuple(stored.get("baselines", ())),
        segment_steps=int(stored.get("segment_steps", config.segment_steps)),
        beta=float(stored.get("beta", config.beta)),
        eps=stored.get("eps", config.eps),
        task=stored.get("task") or task_of((stored.get("env") or {}).get("env_id", "")),
    )
    return write_outputs(config, episodes, traces, train_df, meta)


def _with_mode(episodes: pd.DataFrame) -> pd.DataFrame:
    """Episodes of runs before the baselines have no ``mode``: the alpha mix or the expert."""
    if "mode" in episodes:
        return episodes
    mode = np.where(episodes["method"] == "expert", "expert", "mix")
    return episodes.assign(mode=mode)


def _trace_policies(labels: dict[str, dict[str, Any]]) -> list[str]:
    """Seed-0 agents of alpha 0 and 0.8 (the paper's Figures 5-6) and the expert."""
    keep = ["expert"]
    for key, lab in labels.items():
        if lab["train_seed"] == 0 and lab["rest"] == "all" and lab["alpha"] in (0.0, 0.8):
            keep.append(key)
    return keep


def _order(table: pd.DataFrame, config: ReproduceConfig) -> pd.DataFrame:
    order = {m.name: i for i, m in enumerate(config.methods())}
    order["expert"] = len(order)
    rank = table["method"].map(order).fillna(len(order) + 1)
    return table.iloc[np.argsort(rank.to_numpy(), kind="stable")].reset_index(drop=True)


def _metadata(config: ReproduceConfig) -> dict[str, Any]:
    cfg = dataclasses.asdict(config)
    cfg["demos"], cfg["out"] = str(config.demos), str(config.out)
    cfg["env"] = dataclasses.asdict(config.env)
    cfg["eps"] = config.selection_eps
    cfg["methods"] = {m.name: m.selection.to_dict() for m in config.methods()}
    return run_metadata(
        config=cfg, train_seeds=list(config.train_seeds), eval_seed=config.eval_seed
    )


_fmt = functools.partial(fmt_ci, blank_missing=True)
"""A table cell, blank where the row has no value (e.g. paired columns of the expert)."""


def render_markdown(table: pd.DataFrame, meta: dict[str, Any], *, paper: bool = True) -> str:
    """Our Table 1 (means with 95% crossed bootstrap CIs) and, for CarRacing, the paper's,
    as Markdown.

    Safety is shown with 1 decimal for pixel distances and 3 for margins below 1
    (the rehabilitation task's normalised limits). Violation columns (steps beyond the
    expert's limit ``d_s``; episodes with one) appear when the evaluation measured them; the
    paired columns when plain BC is a row.
    """
    sd = 1 if table["safety_mean"].abs().max() >= 1 else 3
    rd = 0 if sd == 1 else 2
    violations = "violation_steps" in table and table["violation_steps"].notna().any()
    paired = "d_reward" in table
    head = ["method", "reward", "safety mean", "safety std", "safety min", "off-road steps"]
    if violations:
        head += ["violation steps", "episodes with a violation"]
    head += ["critical share", "seeds x tracks"]
    if paired:
        head += ["reward - plain BC", "safety - plain BC", "seeds better than plain BC"]
    rows = []
    for _, r in table.iterrows():
        cells = [
            str(r["method"]),
            _fmt(r, "reward", rd),
            _fmt(r, "safety_mean", sd),
            _fmt(r, "safety_std", sd),
            _fmt(r, "safety_min", sd),
            _fmt(r, "offroad_steps"),
        ]
        if violations:
            n_viol = r.get("episodes_with_violation")
            cells += [
                _fmt(r, "violation_steps"),
                "" if pd.isna(n_viol) else f"{int(n_viol)}/{int(r['n_episodes'])}",
            ]
        cells += [
            _fmt(r, "critical_share", 2),
            f"{int(r['n_train_seeds'])}x{int(r['n_tracks'])}",
        ]
        if paired:
            better = (
                ""
                if pd.isna(r.get("seeds_better"))
                else f"{int(r['seeds_better'])}/{int(r['n_seeds_paired'])} seeds better"
            )
            cells += [_fmt(r, "d_reward", rd), _fmt(r, "d_safety_mean", sd), better]
        rows.append(cells)
    lines = [markdown_table(rows, head)]
    if paper:
        paper_rows = [
            [
                f"{r['alpha']:g}",
                f"{r['reward']:.1f}",
                f"{r['safety_mean']:.2f}",
                f"{r['safety_std']:.2f}",
            ]
            for _, r in PAPER_TABLE1.iterrows()
        ]
        lines += [
            "",
            "Paper (Boecking & Philipp 2020, Table 1; 2 episodes, 1 training run):",
            "",
            markdown_table(paper_rows, ["alpha", "reward", "safety mean", "safety std"]),
        ]
    lines += [
        "",
        "Rows: alpha=0 (rest=all) is plain BC and alpha=1 BC on T_eps only; BC-Safe trains "
        "only on segments of K consecutive scored steps that never enter T_eps; cost-weighted "
        "BC draws every demonstration with weight 1 + beta * (1 - g / g_max), g its margin to "
        "the limit d_s. Values: mean [95% crossed bootstrap CI: training seeds and held-out "
        "tracks resampled independently, since every agent ran on the same tracks]. "
        + (
            "Paired columns: the difference to plain BC on the same (training seed, track) "
            "cells, same bootstrap; k/n seeds better: training seeds whose mean reward over "
            "the tracks beats plain BC's same seed. "
            if paired
            else ""
        )
        + (
            "Violations: steps beyond the expert's limit d_s in any dimension. "
            if violations
            else ""
        )
        + f"Code {meta['git_revision']}, command `{meta['command']}`, "
        f"{meta.get('seconds', '?')} s."
        + (
            f" Re-rendered from the stored episodes by `{meta['rendered']['command']}` "
            f"at {meta['rendered']['git_revision']}."
            if "rendered" in meta
            else ""
        ),
        "",
    ]
    return "\n".join(lines)
