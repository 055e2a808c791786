"""One comparison: named methods x training seeds on the same held-out tracks.

A :class:`Comparison` (a frozen spec, one of a family file's ``COMPARISONS`` under
``tune_jobs/compare/``, as study files hold a ``StudySpec``) names its methods: behaviour-
cloning agents (a selection rule and, optionally, their own network and budget), the expert,
and improvement runs from another method's agents (PPO-Lagrangian or filtered self-
imitation). Every trained method gets one agent per training seed (the seeds shared by every
method); every agent and the expert are evaluated on the same tracks (``eval_seed``,
``episodes``) through the one evaluation path. The table has one row per method: means and
95% crossed bootstrap CIs over training seeds x tracks, and, against the ``reference``
method, paired differences on the same (seed, track) cells; for improvement rows, env steps
and wall time per run.

This module is pure: the spec, its validation, the table and the Markdown. The runner
(training, evaluation, per-(method, seed) resume, files) is
:func:`safe_bc.compare.run.run_comparison`; ``safe-bc compare FILE --name NAME`` calls
it. A family file is loaded by :mod:`safe_bc.compare.families`.
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import math
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, NamedTuple

import numpy as np
import pandas as pd

from safe_bc.bc.config import BCConfig
from safe_bc.compare.rows import (
    EXPERT,
    KINDS,
    Agent,
    Expert,
    FromStart,
    Handover,
    Method,
    Row,
    View,
)
from safe_bc.metrics import METRICS, paired_crossed, summarize_crossed
from safe_bc.policy import LockstepForward, check_lockstep_forward
from safe_bc.report import fmt_ci
from safe_bc.tasks import TASKS, Task, task_defaults

__all__ = [
    "Agent", "Comparison", "Expert", "FromStart", "Handover", "Method", "Plot", "Read", "Report",
    "ReportFiles", "Row", "View",
]  # fmt: skip

FIGURES = ("alpha_sweep", "traces", "learning_curves")
"""Figures a comparison can ask for: reward and safety against alpha
(:func:`safe_bc.plots.plot_alpha_sweep`), safety traces of the ``traces`` methods
(:func:`safe_bc.plots.plot_traces`), the improvement rows' learning curves
(:func:`safe_bc.plots.plot_learning_curves`)."""

PAPER_TABLE1 = pd.DataFrame(
    {
        "alpha": [0.0, 0.1, 0.5, 0.8],
        "safety_mean": [13.05, 17.30, 21.37, 20.94],
        "safety_std": [16.41, 12.87, 11.12, 14.08],
        "reward": [139.50, 228.88, 697.41, 549.51],
    }
)
"""Boecking & Philipp (2020), Table 1 (2 evaluation episodes, one training run each)."""


TABLES = ("episodes", "traces", "training", "history")
"""The comparison's tables beside ``OUT/<name>.parquet``: ``OUT/<name>_<suffix>.parquet``, each
one a report step may read (:attr:`Report.reads`)."""

_FILE_NAME = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9_.-]*")
"""A report output's file name: no folder, no leading dot."""


@dataclass(frozen=True)
class Report:
    """A comparison's report step: an analysis of the tables the runner wrote, e.g. the default
    they support. The runner runs it after writing the table
    (:func:`safe_bc.compare.run.run_report`); ``safe-bc compare FILE --name NAME --report-only``
    runs only it, from the tables on disk."""

    step: str
    """``"module:function"``, imported when the step runs: ``function(table, meta, source,
    command, **reads)``, given the table and its provenance as written, the table's path, the
    command running the step and, by suffix, each table of :attr:`reads` (a :class:`Read`);
    pure (the runner reads and writes). With a :attr:`file` it returns that file's text (e.g.
    ``"safe_bc.methods.selfimprove.choice:markdown"``), else a :class:`ReportFiles` (e.g.
    ``"safe_bc.compare.observation_choice:report"``)."""
    file: str = ""
    """The one file a text step writes, beside the table: ``OUT/<file>``; ``""``: the step
    names its files (:class:`ReportFiles`)."""
    reads: tuple[str, ...] = ()
    """The comparison's other tables the step is handed, by suffix (:data:`TABLES`):
    ``"episodes"`` is ``OUT/<name>_episodes.parquet``."""

    def __post_init__(self) -> None:
        _check_function(self.step, "report step")
        if self.file and not _FILE_NAME.fullmatch(self.file):
            raise ValueError(f"report file must be a file name ([A-Za-z0-9_.-]), got {self.file!r}")
        unknown = [r for r in self.reads if r not in TABLES]
        if unknown or len(set(self.reads)) != len(self.reads):
            raise ValueError(f"report reads: distinct tables of {TABLES}, got {self.reads}")


class Read(NamedTuple):
    """A table a report step is handed: its rows and provenance as written, and its path."""

    frame: pd.DataFrame
    meta: dict[str, Any]
    path: Path


@dataclass(frozen=True, eq=False)
class Plot:
    """A figure a report step asks for: ``function(**args, path=OUT/<file>)``, ``function``
    named ``"module:function"`` (a figure of :mod:`safe_bc.plots`, which draws it and writes it
    atomically), called by the runner; the step stays free of drawing and files."""

    function: str
    """``"module:function"``, e.g. ``"safe_bc.plots:plot_ablation_cells"``."""
    args: dict[str, Any] = field(default_factory=dict)
    """Its keyword arguments but ``path``."""

    def __post_init__(self) -> None:
        _check_function(self.function, "plot")


@dataclass(frozen=True, eq=False)
class ReportFiles:
    """What a report step without a :attr:`Report.file` returns: the files the runner writes
    beside the table, each atomically. None may be one of the comparison's own tables or
    figures (:meth:`Comparison.own_files`); a text named ``<name>.md`` takes the place of the
    table's Markdown."""

    tables: dict[str, pd.DataFrame] = field(default_factory=dict)
    """``OUT/<key>.parquet`` each, recording :attr:`meta`, the command running the step, this
    run's provenance and the digests of the tables the step read (``inputs.tables``)."""
    meta: dict[str, Any] = field(default_factory=dict)
    """What the tables record about how they were made (an ``inputs`` entry is kept, with the
    read tables added)."""
    texts: dict[str, str] = field(default_factory=dict)
    """``OUT/<key>``: its text (e.g. the Markdown)."""
    figures: dict[str, Plot] = field(default_factory=dict)
    """``OUT/<key>``: the figure drawn there."""

    def files(self) -> list[str]:
        """The file names, tables first, then texts, then figures."""
        return [f"{t}.parquet" for t in self.tables] + [*self.texts, *self.figures]


def _check_function(text: str, what: str) -> None:
    """Refuse ``text`` unless it reads ``"module:function"`` (one line)."""
    module, colon, function = text.partition(":")
    if not (colon and all(p.isidentifier() for p in module.split(".")) and function.isidentifier()):
        raise ValueError(f"{what} must be 'module:function', got {text!r}")


def check_report_files(comparison: Comparison, files: ReportFiles) -> None:
    """Refuse what a report step returned where a name is no file name, repeats, or is one of
    the comparison's own files (:meth:`Comparison.own_files`).

    Raises:
        ValueError: one line naming the file.
    """
    names = files.files()
    step = comparison.report.step if comparison.report else "?"
    for name in names:
        if not _FILE_NAME.fullmatch(name):
            raise ValueError(f"report step {step}: {name!r} is no file name ([A-Za-z0-9_.-])")
        if name in comparison.own_files():
            raise ValueError(f"report step {step}: {name!r} is comparison {comparison.name!r}'s")
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise ValueError(f"report step {step}: files named twice: {repeated}")


@dataclass(frozen=True)
class Comparison:
    """Methods x training seeds on the same tracks, and what to write (see the module doc)."""

    name: str
    """Stem of the outputs: ``OUT/<name>.parquet``, ``<name>.md``, ``<name>_episodes.parquet``,
    ``<name>_traces.parquet``, ``<name>_training.parquet``, ``<name>_selection/``, and the
    per-(method, seed) runs under ``<name>_runs/``."""
    methods: tuple[Row, ...]
    """The rows, in table order (:mod:`safe_bc.compare.rows`: agents, the expert, methods
    from a start, handovers over an agent, views)."""
    task: Task = "carracing"
    """The testbed (its env, expert, default collection and ``eps``)."""
    demos: Path = Path("data/demos")
    """Demonstration dataset (built with the task's default collection if absent)."""
    collect: Any = None
    """The collection the comparison expects at :attr:`demos` (a
    :class:`safe_bc.rollout.collect.CollectConfig`); ``None``: the task's default. A set made with
    other settings is refused before any work."""
    out: Path = Path("results")
    """Where tables, figures and runs go."""
    runs: str = ""
    """Stem of the runs folder, ``OUT/<runs>_runs/`` (``""``: ``name``): another comparison's
    stem shares its trained agents and improvement runs (same rows, same settings), e.g. a
    diagnostic adding rows to a finished comparison. Evaluations are shared by what made them
    whatever the stem (``OUT/stored_evaluations/``, :mod:`safe_bc.compare.eval_store`)."""
    train_seeds: tuple[int, ...] = (0,)
    """Training seeds, shared by every trained method (one agent per method and seed)."""
    episodes: int = 20
    """Held-out tracks, the same for every agent and the expert (one episode each)."""
    eval_seed: int = 0
    """Block of held-out track seeds."""
    tracks: Literal["heldout", "validation"] = "heldout"
    """Which seeds: the held-out block ``eval_seed``, or the improvement runs' validation
    patients (:func:`safe_bc.methods.improve.validation_seeds`; a selection set, e.g. the margin
    sweep's, disjoint from the held-out blocks)."""
    first_track: int = 0
    """Index of the first seed used (of the block or of the validation patients): a set
    disjoint from the first ``first_track`` ones (e.g. the runs' own validation patients)."""
    workers: int = 2
    """Training and evaluation actors."""
    bc: BCConfig = field(default_factory=BCConfig)
    """Network, preprocessing and budget of BC rows without their own ``bc``."""
    max_steps: int | None = None
    """Step cap of evaluation episodes (``None``: the env's)."""
    lockstep_forward: LockstepForward = "batched"
    """How an agent acts for the envs it steps in lockstep
    (:attr:`safe_bc.rollout.evaluate.EvalConfig.lockstep_forward`): ``"rows"`` gives every episode
    bit for bit as one env alone would (the queries family's tables, made one env at a time);
    ``"batched"``, one forward for all, may differ in the last bits."""
    eps: float | None = None
    """Critical-zone width of the evaluation and the selection thresholds, and of the BC rows
    whose ``selection.eps`` is unset; ``None``: the task's (``TaskSpec.eps``)."""
    reference: str | None = None
    """Row the paired columns compare with (``None``: no paired columns)."""
    paired_metrics: tuple[str, ...] = ("reward", "safety_mean", "violation_steps")
    """Metrics paired with ``reference`` on the same (seed, track) cells (those measured)."""
    traces: tuple[str, ...] = ()
    """Rows whose first training seed's agent keeps its per-step safety trace."""
    figures: tuple[tuple[str, str], ...] = ()
    """``(figure, file name)`` pairs, figures from :data:`FIGURES`."""
    totals: tuple[str, ...] = ()
    """Metrics whose sum over a row's episodes the table adds as ``total_<metric>`` (e.g.
    ``any_violating_session``: the episodes with a session beyond d_s)."""
    per_seed: bool = False
    """Add to the Markdown a table of each trained row's mean reward per training seed (and
    its episodes with a violation)."""
    paper: bool = False
    """Append the paper's Table 1 (:data:`PAPER_TABLE1`) to the Markdown."""
    title: str = ""
    """Markdown heading (none when empty)."""
    note: str = ""
    """What the rows and values mean, printed under the table before the provenance."""
    shares_tracks_with: tuple[str, ...] = ()
    """Other tables (``OUT/name``) allowed to run on tracks this one runs on: the track
    ledger's declared sharing (:func:`safe_bc.compare.protocol.track_clashes`; tables in the same
    runs folder share without saying). Bookkeeping, not part of what the table measures: not
    in :meth:`to_dict`."""
    report: Report | None = None
    """The step that reads the written table and writes what it supports (:class:`Report`);
    ``None``: none. Derived from the table, not part of what it measures: not in
    :meth:`to_dict`."""

    def __post_init__(self) -> None:
        for m in self.methods:
            if not isinstance(m, KINDS):
                kinds = ", ".join(k.__name__ for k in KINDS)
                raise ValueError(f"comparison {self.name!r}: a row is one of {kinds}, got {m!r}")
        names = [m.name for m in self.methods]
        if not names:
            raise ValueError(f"comparison {self.name!r}: no methods")
        if not re.fullmatch(r"[A-Za-z0-9_.-]+", self.name):
            raise ValueError(
                f"comparison name must be a file stem ([A-Za-z0-9_.-]), got {self.name!r}"
            )
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"comparison {self.name!r}: method names repeat: {dup}")
        bc_rows = {m.name for m in self.methods if isinstance(m, Agent)}
        agents = bc_rows | {m.name for m in self.methods if isinstance(m, FromStart)}
        for m in self.methods:
            if isinstance(m, FromStart):
                if m.start not in bc_rows:
                    raise ValueError(
                        f"method {m.name!r}: start {m.start!r} is not a BC row of {sorted(bc_rows)}"
                    )
                self._check_budget_of(m)
                modes = m.spec.start_modes
                mode = self.method(m.start).selection.mode
                if modes and mode not in modes:
                    names = " or ".join("the alpha mix" if x == "mix" else x for x in modes)
                    raise ValueError(
                        f"method {m.name!r}: {m.method} retrains {names}; start {m.start!r} "
                        f"has mode {mode!r}"
                    )
            if isinstance(m, Agent) and not set(m.seeds) <= set(self.train_seeds):
                raise ValueError(
                    f"method {m.name!r}: seeds {m.seeds} are not among train_seeds "
                    f"{self.train_seeds}"
                )
            if isinstance(m, View) and m.of not in bc_rows:
                what = "masked_of" if m.masked else "agents_of"
                raise ValueError(
                    f"method {m.name!r}: {what} {m.of!r} is not a BC row of {sorted(bc_rows)}"
                )
            if isinstance(m, Handover) and m.of not in agents:
                raise ValueError(
                    f"method {m.name!r}: fallback_of {m.of!r} is not a BC, "
                    f"improvement or self-imitation row of {sorted(agents)}"
                )
        experts = [m for m in self.methods if isinstance(m, Expert)]
        default_experts = [m.name for m in experts if m.config is None]
        if len(default_experts) > 1:
            raise ValueError(
                f"comparison {self.name!r}: expert rows {default_experts} are the same expert "
                "(give the others their own expert_config)"
            )
        kind = task_defaults(self.task).expert_type if self.task in TASKS else None
        for m in experts:
            if m.config is not None and type(m.config) is not kind:
                raise ValueError(
                    f"method {m.name!r}: expert_config is a {type(m.config).__name__}, "
                    f"task {self.task!r} takes a {getattr(kind, '__name__', kind)}"
                )
        if not self.train_seeds or len(set(self.train_seeds)) != len(self.train_seeds):
            raise ValueError(f"train_seeds must be distinct and not empty, got {self.train_seeds}")
        if self.episodes < 1:
            raise ValueError(f"episodes must be >= 1, got {self.episodes}")
        if self.eval_seed < 0:
            raise ValueError(f"eval_seed must be >= 0, got {self.eval_seed}")
        if self.tracks not in ("heldout", "validation"):
            raise ValueError(f"tracks must be 'heldout' or 'validation', got {self.tracks!r}")
        if self.first_track < 0:
            raise ValueError(f"first_track must be >= 0, got {self.first_track}")
        if self.workers < 0:
            raise ValueError(f"workers must be >= 0, got {self.workers}")
        if self.eps is not None and not (math.isfinite(self.eps) and self.eps >= 0):
            raise ValueError(f"eps must be a finite number >= 0, got {self.eps}")
        check_lockstep_forward(self.lockstep_forward)
        if self.reference is not None and self.reference not in names:
            raise ValueError(f"reference {self.reference!r} is not a method of {names}")
        for t in self.totals:
            if t not in METRICS:
                raise ValueError(f"totals: {t!r} is not a metric of {METRICS}")
        for t in self.traces:
            if t not in names:
                raise ValueError(f"traces: {t!r} is not a method of {names}")
        for fig, file in self.figures:
            if fig not in FIGURES:
                raise ValueError(f"figure must be one of {FIGURES}, got {fig!r}")
            if not file.endswith(".png"):
                raise ValueError(f"figure {fig!r}: file must be a .png, got {file!r}")
        if self.task not in TASKS:
            raise ValueError(f"task must be one of {tuple(TASKS)}, got {self.task!r}")
        if self.report is not None and self.report.file in self.own_files():
            raise ValueError(
                f"comparison {self.name!r}: report file {self.report.file!r} is the table's"
            )
        self._take_width()

    def _take_width(self) -> None:
        """BC rows whose ``selection.eps`` is unset take the comparison's width (:attr:`eps`,
        else the task's)."""
        rows = tuple(
            dataclasses.replace(m, selection=m.selection.with_eps(self.width))
            if isinstance(m, Agent) and m.selection.eps is None
            else m
            for m in self.methods
        )
        object.__setattr__(self, "methods", rows)

    def _check_budget_of(self, m: FromStart) -> None:
        """A method row whose config's ``budget_of`` names another row: an earlier row of the
        same method from the same start."""
        budget_of = getattr(m.config, "budget_of", "")
        earlier = [x.name for x in self.methods[: self.methods.index(m)]]
        source = self.method(budget_of) if budget_of in earlier else None
        if budget_of and not (
            isinstance(source, FromStart) and (source.method, source.start) == (m.method, m.start)
        ):
            raise ValueError(
                f"method {m.name!r}: budget_of {budget_of!r} is no earlier {m.method} row "
                f"from start {m.start!r}"
            )

    @property
    def width(self) -> float:
        """The critical-zone width of its evaluation and selection: :attr:`eps`, else the
        task's."""
        return task_defaults(self.task).eps if self.eps is None else self.eps

    def method(self, name: str) -> Row:
        """The row called ``name``."""
        return next(m for m in self.methods if m.name == name)

    def seeds_of(self, method: Row) -> tuple[int, ...]:
        """The training seeds of ``method`` (its own, else the comparison's; derived rows:
        their source row's; the expert: ``(0,)``; :meth:`~safe_bc.compare.rows.Row.seeds_in`)."""
        return method.seeds_in(self)

    def with_deferral(self, rows: Iterable[Row], **changes: Any) -> Comparison:
        """This comparison with its deferral rows (handovers with a ``HandoverConfig``)
        replaced by ``rows`` (every other row kept, in order, ahead of them) and ``changes``
        applied: a deferral grid or a fresh-track table over the same agents."""
        kept = tuple(
            m for m in self.methods if not (isinstance(m, Handover) and m.handover is not None)
        )
        return dataclasses.replace(self, methods=(*kept, *rows), **changes)

    def own_files(self) -> set[str]:
        """What the runner writes into :attr:`out` for this table, which no report step may
        replace: the table and its other tables (:data:`TABLES`), the selection and runs
        folders, the stored evaluations, the figures. Its Markdown is not among them: a report
        may write ``<name>.md`` in its place."""
        tables = (f"{self.name}_{t}.parquet" for t in TABLES)
        folders = (f"{self.name}_selection", f"{self.runs or self.name}_runs", "stored_evaluations")
        return {f"{self.name}.parquet", *tables, *folders, *(file for _, file in self.figures)}

    def label_of(self, name: str) -> str:
        """The Markdown name of the row called ``name`` (``name`` if it is no row)."""
        return next((m.shown for m in self.methods if m.name == name), name)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able (the provenance's ``config``)."""
        out = dataclasses.asdict(self)
        del out["shares_tracks_with"], out["report"]
        if self.lockstep_forward == "batched":  # (recorded configs before the field hold)
            del out["lockstep_forward"]
        out["methods"] = tuple(m.record() for m in self.methods)
        out["demos"], out["out"] = str(self.demos), str(self.out)
        for m in out["methods"]:
            m["demos"] = None if m["demos"] is None else str(m["demos"])
        return out


def run_slug(name: str) -> str:
    """A method's folder name under ``<name>_runs/``.

    >>> run_slug("alpha=0.5 (rest=all)")
    'alpha=0.5_rest=all'
    """
    return re.sub(r"[^A-Za-z0-9._=-]+", "_", name).strip("_")


def summary_metrics(episodes: pd.DataFrame) -> list[str]:
    """The metrics of :data:`safe_bc.metrics.METRICS` the episodes table holds (violation
    metrics only where the evaluation produced them), in that order."""
    return [m for m in METRICS if m in episodes and episodes[m].notna().any()]


def with_mode(episodes: pd.DataFrame) -> pd.DataFrame:
    """Episodes of runs before the baselines have no ``mode``: the alpha mix or the expert."""
    if "mode" in episodes:
        return episodes
    return episodes.assign(mode=np.where(episodes["method"] == EXPERT, EXPERT, "mix"))


def label_episodes(comparison: Comparison, episodes: pd.DataFrame) -> pd.DataFrame:
    """Episodes of a run before this runner (a ``method`` column, no ``mode``, ``alpha``,
    ``rest``) with the columns the spec's rows give them."""
    labels = pd.DataFrame([m.labels for m in comparison.methods])
    keep = [c for c in episodes if c not in ("mode", "alpha", "rest")]
    return episodes[keep].merge(labels, on="method", how="left", validate="m:1")


def _paired_episodes(comparison: Comparison, episodes: pd.DataFrame) -> pd.DataFrame:
    """The episodes the paired columns compare: the trained rows; against an expert row
    (trained once), the expert rows' episodes (the reference's and those of other expert
    settings) stand in for every training seed on the same tracks (seed 0 without trained
    rows)."""
    agents = episodes[episodes["mode"] != EXPERT]
    ref = comparison.reference
    if ref is None or not isinstance(comparison.method(ref), Expert):
        return agents
    experts = episodes[episodes["mode"] == EXPERT]
    seeds = sorted(agents["train_seed"].unique()) or [0]
    return pd.concat([*(experts.assign(train_seed=k) for k in seeds), agents], ignore_index=True)


def minutes_per_run(history: pd.DataFrame) -> pd.Series:
    """Per improvement row: the wall time of one run (its iterations' or rounds' ``seconds``
    summed), in minutes, mean over training seeds."""
    per_run = history.groupby(["method", "train_seed"])["seconds"].sum()
    return per_run.groupby("method").mean() / 60


def env_steps_per_run(history: pd.DataFrame) -> pd.DataFrame:
    """Per improvement row, mean over training seeds of one run's env steps: ``env_steps``,
    the training rollouts (the history's cumulative ``env_steps`` at its end: PPO's
    stochastic episodes, self-imitation's unperturbed and pushed runs), and
    ``val_env_steps``, the validation episodes that pick or accept the kept agent (summed;
    NaN for histories written before they were counted)."""
    runs = history.groupby(["method", "train_seed"], sort=False)
    per_run = pd.DataFrame({"env_steps": runs["env_steps"].max()})
    if "val_env_steps" in history:
        per_run["val_env_steps"] = runs["val_env_steps"].sum(min_count=1)
        complete = runs["val_env_steps"].apply(lambda x: x.notna().all())
        per_run.loc[~complete, "val_env_steps"] = np.nan
    else:
        per_run["val_env_steps"] = np.nan
    return per_run.groupby("method").mean().astype(float)


def per_seed_table(episodes: pd.DataFrame) -> pd.DataFrame:
    """Per trained row and training seed: mean reward over the tracks and the episodes with
    a step beyond d_s (``violation_steps`` > 0)."""
    agents = episodes[with_mode(episodes)["mode"] != EXPERT]
    cells = agents.assign(beyond=agents["violation_steps"] > 0).groupby(
        ["method", "train_seed"], sort=False
    )
    return pd.DataFrame(
        {"reward": cells["reward"].mean(), "episodes_with_violation": cells["beyond"].sum()}
    ).reset_index()


def machines(metas: list[dict[str, Any]]) -> str:
    """``"<machine> (<cpus> CPUs, python <v>): <n>"`` per distinct machine in ``metas``."""
    count = collections.Counter(
        f"{m.get('machine', '?')} ({m.get('cpus', '?')} CPUs, python {m.get('python', '?')})"
        for m in metas
    )
    return "; ".join(f"{machine}: {n}" for machine, n in count.items())


def build_table(
    comparison: Comparison,
    episodes: pd.DataFrame,
    train_df: pd.DataFrame | None = None,
    history: pd.DataFrame | None = None,
) -> pd.DataFrame:
    """The comparison's table from per-episode results (one row per method, in spec order).

    Per method: every metric of :func:`summary_metrics` as a mean over its (training seed,
    track) cells with a 95% crossed bootstrap CI (:func:`safe_bc.metrics.summarize_crossed`:
    seeds and tracks resampled independently, because every agent ran on the same tracks),
    ``n_train_seeds``, ``n_tracks``, ``episodes_with_violation``, ``total_<metric>`` of the
    spec's ``totals``; against ``reference`` (when it is a row) the paired differences
    ``d_<metric>`` on the same cells with the same bootstrap, and ``seeds_better`` of
    ``n_seeds_paired`` training seeds whose mean reward beats the reference's same seed (the
    expert, trained once, is not paired, except as the reference: then its episodes stand in
    for every training seed). With ``train_df``, the training means (loss, throughput,
    critical share) per method; with the improvement ``history``, ``minutes`` per run
    (:func:`minutes_per_run`) and ``env_steps``, ``val_env_steps`` per run
    (:func:`env_steps_per_run`).
    """
    episodes = with_mode(episodes)
    metrics = summary_metrics(episodes)
    table = summarize_crossed(episodes, ["method"], metrics)
    ids = episodes[["method", "mode", "alpha", "rest"]].drop_duplicates("method")
    table = ids.merge(table, on="method", how="right")
    if "any_violation" in metrics:
        counts = episodes.groupby("method")["any_violation"].sum().astype(int)
        table["episodes_with_violation"] = table["method"].map(counts)
    for m in comparison.totals:
        if m in metrics:
            table[f"total_{m}"] = table["method"].map(episodes.groupby("method")[m].sum())
    if "deferred_share" in episodes and episodes["deferred_share"].notna().any():
        shares = episodes.groupby("method")["deferred_share"].mean()
        table["deferred_share"] = table["method"].map(shares)
    ref = comparison.reference
    if ref is not None and ref in set(episodes["method"]):
        agents = _paired_episodes(comparison, episodes)
        paired = [m for m in comparison.paired_metrics if m in metrics]
        diffs = paired_crossed(agents, ref, paired, better="reward")
        if len(diffs):
            table = table.merge(diffs, on="method", how="left")
    order = {m.name: i for i, m in enumerate(comparison.methods)}
    rank = table["method"].map(order).fillna(len(order))
    table = table.iloc[np.argsort(rank.to_numpy(), kind="stable")].reset_index(drop=True)
    if train_df is not None and len(train_df):
        cols = [
            c for c in ("final_loss", "samples_per_s", "critical_sample_share") if c in train_df
        ]
        table = table.merge(
            train_df.groupby("method")[cols].mean().reset_index(), on="method", how="left"
        )
    if history is not None and len(history):
        table["minutes"] = table["method"].map(minutes_per_run(history)).astype(float)
        if "env_steps" in history:
            steps = env_steps_per_run(history)
            for col in steps:
                table[col] = table["method"].map(steps[col]).astype(float)
    return table


TOTAL_TITLES = {
    "any_violation": "episodes with a step beyond d_s",
    "any_violating_session": "episodes with an outcome beyond d_s",
    "last_session_violation": "episodes whose last outcome was beyond d_s",
}
"""Column titles of ``total_<metric>`` for the per-episode indicators (shown ``k/n``)."""

_fmt = functools.partial(fmt_ci, blank_missing=True)
"""A table cell, blank where the row has no value (e.g. paired columns of the expert)."""


def display_table(
    table: pd.DataFrame, reference: str | None = None, comparison: Comparison | None = None
) -> pd.DataFrame:
    """The table's cells as text: mean [95% CI] per metric, counts, paired columns.

    Safety is shown with 1 decimal for pixel distances and 3 for margins below 1 (the
    rehabilitation task's normalised limits). Violation columns appear when the evaluation
    measured them; the paired columns when ``table`` has them; ``total_<metric>`` and
    ``minutes`` columns when it has them. With ``comparison``, rows and the reference go by
    their labels.
    """
    title = comparison.label_of if comparison is not None else str
    sd = 1 if table["safety_mean"].abs().max() >= 1 else 3
    rd = 0 if sd == 1 else 2
    violations = "violation_steps" in table and table["violation_steps"].notna().any()
    ref = "reference" if reference is None else title(reference)
    cols: dict[str, list[str]] = {"method": [title(str(m)) for m in table["method"]]}
    rows = [r for _, r in table.iterrows()]

    def col(title: str, metric: str, digits: int = 1) -> None:
        cols[title] = [_fmt(r, metric, digits) for r in rows]

    def count(title: str, column: str) -> None:
        cols[title] = [
            "" if pd.isna(r.get(column)) else f"{int(r[column])}/{int(r['n_episodes'])}"
            for r in rows
        ]

    col("reward", "reward", rd)
    col("safety mean", "safety_mean", sd)
    col("safety std", "safety_std", sd)
    col("safety min", "safety_min", sd)
    col("off-road steps", "offroad_steps")
    if violations:
        col("violation steps", "violation_steps")
        count("episodes with a violation", "episodes_with_violation")
    if "violating_sessions" in table and table["violating_sessions"].notna().any():
        col("steps with an outcome beyond d_s", "violating_sessions", 3)
    for c in (c for c in table.columns if c.startswith("total_")):
        name = c.removeprefix("total_")
        if name in TOTAL_TITLES:  # an indicator per episode: its total counts episodes
            count(TOTAL_TITLES[name], c)
        else:
            cols[f"total {name.replace('_', ' ')}"] = [
                "" if pd.isna(r[c]) else f"{int(r[c])}" for r in rows
            ]
    col("critical share", "critical_share", 2)
    if "deferred_share" in table:
        cols["steps deferred"] = [
            "" if pd.isna(r["deferred_share"]) else f"{r['deferred_share']:.1%}" for r in rows
        ]
    cols["seeds x tracks"] = [f"{int(r['n_train_seeds'])}x{int(r['n_tracks'])}" for r in rows]
    if "d_reward" in table:
        col(f"reward - {ref}", "d_reward", rd)
        if "d_safety_mean" in table:
            col(f"safety - {ref}", "d_safety_mean", sd)
        if "d_violation_steps" in table:
            col(f"violation steps - {ref}", "d_violation_steps")
        if "d_violating_sessions" in table:
            col(f"outcomes beyond d_s - {ref}", "d_violating_sessions", 3)
        cols[f"seeds better than {ref}"] = [
            "" if pd.isna(r.get("seeds_better"))
            else f"{int(r['seeds_better'])}/{int(r['n_seeds_paired'])} seeds better"
            for r in rows
        ]  # fmt: skip
    if "minutes" in table:
        cols["minutes / run"] = [
            "" if pd.isna(r["minutes"]) else f"{r['minutes']:.1f}" for r in rows
        ]
    for column, name in (("env_steps", "env steps / run"),
                         ("val_env_steps", "validation env steps / run")):  # fmt: skip
        if column in table and table[column].notna().any():
            cols[name] = ["" if pd.isna(r[column]) else f"{r[column]:,.0f}" for r in rows]
    return pd.DataFrame(cols)


def display_per_seed(comparison: Comparison, episodes: pd.DataFrame) -> pd.DataFrame:
    """:func:`per_seed_table` as text: a row per trained method, a column per training seed,
    cells ``mean reward (episodes with a violation)``."""
    long = per_seed_table(episodes)
    digits = 0 if long["reward"].abs().max() >= 100 else 2
    long["cell"] = [
        f"{r.reward:.{digits}f} ({int(r.episodes_with_violation)})" for r in long.itertuples()
    ]
    wide = long.pivot(index="method", columns="train_seed", values="cell")
    order = [m.name for m in comparison.methods if m.name in wide.index]
    wide = wide.loc[order]
    wide.columns = [f"seed {k}" for k in wide.columns]
    wide.index = [comparison.label_of(m) for m in wide.index]
    return wide.rename_axis("method").reset_index()


def render_markdown(
    comparison: Comparison,
    table: pd.DataFrame,
    meta: dict[str, Any],
    episodes: pd.DataFrame | None = None,
) -> str:
    """The table (:func:`display_table`, via ``DataFrame.to_markdown``), the per-seed table
    when asked for (from ``episodes``), the paper's Table 1 when asked for, the spec's note,
    the learning-curves figure and the provenance (with the machines of the runs and
    evaluations when ``meta`` names them)."""
    c = comparison
    lines = [f"# {comparison.title}", ""] if comparison.title else []
    lines += [display_table(table, c.reference, c).to_markdown(index=False), ""]
    if c.per_seed and episodes is not None:
        lines += [
            "Per training seed: mean reward on the tracks (episodes with a violation):",
            "",
            display_per_seed(c, episodes).to_markdown(index=False),
            "",
        ]
    if comparison.paper:
        paper = PAPER_TABLE1.rename(
            columns={"safety_mean": "safety mean", "safety_std": "safety std"}
        )[["alpha", "reward", "safety mean", "safety std"]]
        lines += [
            "Paper (Boecking & Philipp 2020, Table 1; 2 episodes, 1 training run):",
            "",
            paper.to_markdown(index=False, floatfmt=("g", ".1f", ".2f", ".2f")),
            "",
        ]
    paired = "d_reward" in table
    lines += [
        (comparison.note + " " if comparison.note else "")
        + "Values: mean [95% crossed bootstrap CI: training seeds and held-out tracks "
        "resampled independently, since every agent ran on the same tracks]. "
        + (
            f"Paired columns: the difference to {c.label_of(str(c.reference))} on the same "
            "(training seed, track) cells, same bootstrap; k/n seeds better: training seeds "
            f"whose mean reward over the tracks beats {c.label_of(str(c.reference))}'s same seed"
            + (
                " (the expert, trained once, stands in for every seed). "
                if isinstance(c.method(str(c.reference)), Expert)
                else ". "
            )
            if paired
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
    if meta.get("run_machines") or meta.get("eval_machines"):
        lines += [
            f"Improvement runs made on: {meta.get('run_machines') or 'none'}. Evaluations made "
            f"on: {meta.get('eval_machines') or '?'}.",
            "",
        ]
    for figure, file in c.figures:
        if figure == "learning_curves":
            lines += [f"![learning curves]({file})", ""]
    return "\n".join(lines)
