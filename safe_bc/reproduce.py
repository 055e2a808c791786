"""Table 1 of the paper, rerun honestly: alpha sweep x both eq. 5 readings x training seeds.

Writes under ``out`` (default ``results/``):

* ``table1.parquet``: one row per method (alpha, reading, and the expert) with means and
  95% bootstrap CIs over training seeds and held-out episodes; metadata records the
  command, seeds, configs and code revision.
* ``table1.md``: the same as Markdown, beside the paper's numbers.
* ``table1_episodes.parquet``: one row per evaluated episode.
* ``table1_selection.parquet``: which demonstrations were critical (thresholds in metadata).
* ``fig4_alpha.png``: reward and safety against alpha with CI error bars.
* ``fig5_6_traces.png``: safety traces of alpha 0 and alpha 0.8 agents and the expert.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pandas as pd

from safe_bc.bc import BCConfig
from safe_bc.collection import stored_expert_config
from safe_bc.data.store import load_demonstrations, write_table_atomic, write_text_atomic
from safe_bc.envs import EnvConfig
from safe_bc.evaluation import EvalConfig, ExpertSource, NetSource
from safe_bc.experiment import RunConfig, save_selection, select_for
from safe_bc.metrics import combined, paired_differences, summarize
from safe_bc.provenance import run_metadata
from safe_bc.selection import SelectionConfig
from safe_bc.tasks import Task, action_bounds, task_defaults

Reading = Literal["all", "noncritical"]

PAPER_TABLE1 = pd.DataFrame(
    {
        "alpha": [0.0, 0.1, 0.5, 0.8],
        "safety_mean": [13.05, 17.30, 21.37, 20.94],
        "safety_std": [16.41, 12.87, 11.12, 14.08],
        "reward": [139.50, 228.88, 697.41, 549.51],
    }
)
"""Boecking & Philipp (2020), Table 1 (2 evaluation episodes, one training run each)."""

SUMMARY_METRICS = (
    "reward",
    "safety_mean",
    "safety_std",
    "safety_min",
    "offroad_steps",
    "critical_share",
    "tiles_visited",
)


@dataclass(frozen=True)
class ReproduceConfig:
    """The Table 1 rerun."""

    demos: Path = Path("data/demos")
    """Demonstration dataset (built with the default collection if absent)."""
    out: Path = Path("results")
    """Where tables and figures go."""
    alphas: tuple[float, ...] = (0.0, 0.1, 0.5, 0.8)
    """Safety focus values (the paper's)."""
    eps: float = 5.0
    """Critical-zone width in pixels (the paper's)."""
    readings: tuple[Reading, ...] = ("all", "noncritical")
    """Both readings of eq. 5: the rest drawn from all of T (text) or from T \\ T_eps."""
    train_seeds: tuple[int, ...] = (0, 1, 2)
    """Training seeds per configuration."""
    episodes: int = 10
    """Held-out evaluation episodes per trained agent (and for the expert)."""
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
        if self.eps < 0:
            raise ValueError(f"eps must be >= 0, got {self.eps}")
        if not self.train_seeds:
            raise ValueError("need at least one training seed")

    @property
    def env(self) -> EnvConfig:
        """The task's environment."""
        return task_defaults(self.task).env


def method_name(alpha: float, reading: str) -> str:
    """Row label of a configuration, e.g. ``alpha=0.5 (rest=all)``."""
    return f"alpha={alpha:g} (rest={reading})"


def run_reproduce(config: ReproduceConfig, *, progress: bool = True) -> pd.DataFrame:
    """Train every (alpha, reading, seed), evaluate them and the expert, write the results."""
    from safe_bc.distributed.collect import ensure_demos
    from safe_bc.distributed.evaluate import evaluate_policies
    from safe_bc.distributed.train import train_many

    started = time.perf_counter()
    ensure_demos(config.demos, task_defaults(config.task).collect_config(), progress=progress)
    demos = load_demonstrations(config.demos)
    meta = _metadata(config)
    config.out.mkdir(parents=True, exist_ok=True)

    base = select_for(demos, SelectionConfig(eps=config.eps, alpha=0.0))
    save_selection(config.out / "table1_selection", demos, base, meta)

    bounds = None if config.env.is_carracing else action_bounds(config.env)
    runs = [(a, r, s) for a in config.alphas for r in config.readings for s in config.train_seeds]
    for alpha, reading, _ in runs:  # fail fast, before any training, on an impossible mix
        select_for(demos, SelectionConfig(eps=config.eps, alpha=alpha, rest=reading)).sampler(
            config.bc.train.batch_size, np.random.default_rng(0)
        )
    run_cfgs = [
        RunConfig(
            SelectionConfig(eps=config.eps, alpha=alpha, rest=reading),
            dataclasses.replace(config.bc, train=dataclasses.replace(config.bc.train, seed=seed)),
        )
        for alpha, reading, seed in runs
    ]
    trained = train_many(
        demos, run_cfgs, workers=config.workers, action_bounds=bounds, progress=progress
    )
    sources: dict[str, Any] = {}
    labels: dict[str, dict[str, Any]] = {}
    train_rows = []
    for (alpha, reading, seed), (result, selection) in zip(runs, trained, strict=True):
        key = f"{method_name(alpha, reading)} seed={seed}"
        sources[key] = NetSource.from_model(result.model, result.config)
        labels[key] = {
            "method": method_name(alpha, reading),
            "alpha": alpha,
            "rest": reading,
            "train_seed": seed,
        }
        train_rows.append(
            {
                **labels[key],
                "final_loss": result.final_loss,
                "samples_per_s": result.samples_per_s,
                "n_critical": selection.n_critical,
            }
        )
    sources["expert"] = ExpertSource(stored_expert_config(config.demos))
    labels["expert"] = {"method": "expert", "alpha": np.nan, "rest": "", "train_seed": 0}

    eval_cfg = EvalConfig(
        episodes=config.episodes,
        workers=config.workers,
        seed=config.eval_seed,
        env=config.env,
        max_steps=config.max_steps,
        eps=config.eps,
    )
    episodes, steps = evaluate_policies(
        sources, eval_cfg, thresholds=base.thresholds, progress=progress
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


def write_outputs(
    config: ReproduceConfig,
    episodes: pd.DataFrame,
    traces: pd.DataFrame,
    train_df: pd.DataFrame,
    meta: dict[str, Any],
) -> pd.DataFrame:
    """Summarise per-episode results into Table 1, its Markdown and the figures."""
    table = summarize(episodes, ["method", "alpha", "rest"], SUMMARY_METRICS, group="train_seed")
    baseline = method_name(0.0, "all") if 0.0 in config.alphas else None
    if baseline is not None:
        agents = episodes[episodes["method"] != "expert"]  # trained once: no seed pairing
        diffs = paired_differences(agents, baseline, ["reward", "safety_mean"])
        table = table.merge(diffs, on="method", how="left") if len(diffs) else table
    table = _order(table, config)
    table = table.merge(
        train_df.groupby("method")[["final_loss", "samples_per_s"]].mean().reset_index(),
        on="method",
        how="left",
    )
    write_table_atomic(config.out / "table1.parquet", table, meta)
    markdown = render_markdown(table, meta, paper=config.env.is_carracing)
    write_text_atomic(config.out / "table1.md", markdown)
    from safe_bc.plots import plot_alpha_sweep, plot_traces

    paper = PAPER_TABLE1 if config.env.is_carracing else None
    plot_alpha_sweep(table, config.out / "fig4_alpha.png", paper=paper)
    labels = {p: {"method": m} for p, m in episodes[["policy", "method"]].drop_duplicates().values}
    plot_traces(traces, labels, config.out / "fig5_6_traces.png")
    return table


def rerender(config: ReproduceConfig) -> pd.DataFrame:
    """Rebuild Table 1, its Markdown and figures from the stored per-episode results.

    Nothing is trained or evaluated again; the metadata keeps the original run's
    command and revision and adds the re-rendering's under ``rendered``.
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
        task=stored.get("task", "carracing" if "CarRacing" in str(stored.get("env")) else "rehab"),
    )
    return write_outputs(config, episodes, traces, train_df, meta)


def _trace_policies(labels: dict[str, dict[str, Any]]) -> list[str]:
    """Seed-0 agents of alpha 0 and 0.8 (the paper's Figures 5-6) and the expert."""
    keep = ["expert"]
    for key, lab in labels.items():
        if lab["train_seed"] == 0 and lab["rest"] == "all" and lab["alpha"] in (0.0, 0.8):
            keep.append(key)
    return keep


def _order(table: pd.DataFrame, config: ReproduceConfig) -> pd.DataFrame:
    order = {
        method_name(a, r): i
        for i, (r, a) in enumerate((r, a) for r in config.readings for a in config.alphas)
    }
    order["expert"] = len(order)
    return table.sort_values("method", key=lambda c: c.map(order)).reset_index(drop=True)


def _metadata(config: ReproduceConfig) -> dict[str, Any]:
    cfg = dataclasses.asdict(config)
    cfg["demos"], cfg["out"] = str(config.demos), str(config.out)
    cfg["env"] = dataclasses.asdict(config.env)
    return run_metadata(
        config=cfg, train_seeds=list(config.train_seeds), eval_seed=config.eval_seed
    )


def _fmt(row: pd.Series, m: str, digits: int = 1) -> str:
    return f"{row[m]:.{digits}f} [{row[m + '_lo']:.{digits}f}, {row[m + '_hi']:.{digits}f}]"


def _paired_cells(row: pd.Series, sd: int) -> str:
    if pd.isna(row.get("d_reward")):
        return " | |"
    return f" {_fmt(row, 'd_reward', 0 if sd == 1 else 2)} | {_fmt(row, 'd_safety_mean', sd)} |"


def render_markdown(table: pd.DataFrame, meta: dict[str, Any], *, paper: bool = True) -> str:
    """Our Table 1 (means with 95% CIs) and, for CarRacing, the paper's, as Markdown.

    Safety is shown with 1 decimal for pixel distances and 3 for margins below 1
    (the rehabilitation task's normalised limits).
    """
    sd = 1 if table["safety_mean"].abs().max() >= 1 else 3
    paired = "d_reward" in table
    lines = [
        "| method | reward | safety mean | safety std | safety min | off-road steps "
        "| critical share | n |" + (" reward - plain BC | safety - plain BC |" if paired else ""),
        "|---|---|---|---|---|---|---|---|" + ("---|---|" if paired else ""),
    ]
    for _, r in table.iterrows():
        lines.append(
            f"| {r['method']} | {_fmt(r, 'reward', 0 if sd == 1 else 2)} "
            f"| {_fmt(r, 'safety_mean', sd)} | {_fmt(r, 'safety_std', sd)} "
            f"| {_fmt(r, 'safety_min', sd)} | {_fmt(r, 'offroad_steps')} "
            f"| {_fmt(r, 'critical_share', 2)} | {int(r['n_train_seeds'])}x"
            f"{int(r['n_episodes'] // max(r['n_train_seeds'], 1))} |"
            + (_paired_cells(r, sd) if paired else "")
        )
    if paper:
        lines += [
            "",
            "Paper (Boecking & Philipp 2020, Table 1; 2 episodes, 1 training run):",
            "",
            "| alpha | reward | safety mean | safety std |",
            "|---|---|---|---|",
        ]
        for _, r in PAPER_TABLE1.iterrows():
            lines.append(
                f"| {r['alpha']:g} | {r['reward']:.1f} | {r['safety_mean']:.2f} "
                f"| {r['safety_std']:.2f} |"
            )
    lines += [
        "",
        f"Values: mean [95% bootstrap CI over training seeds and held-out episodes]; the "
        f"last two columns pair each agent with plain BC (alpha=0, rest=all) of the same "
        f"training seed on the same tracks. "
        f"Code {meta['git_revision']}, command `{meta['command']}`, "
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
