"""What each ``safe-bc`` command takes: one frozen record per command, paths plus the configs.

The command line is generated from these records (``safe_bc.cli.commands``, tyro): a field is a
flag,
its docstring the flag's help, a nested config's fields dotted flags (``--selection.eps``,
``--bc.train.lr``: the names a study's search space uses). Range checks live in the configs'
``__post_init__``. ``None`` defaults mean "the task's" or "the config's own default", so no
default is written twice. The functions of :mod:`safe_bc.cli.api` take these records. The
records of the commands from before ``safe-bc method NAME`` live beside their methods' code
(:data:`safe_bc.methods.METHOD_COMMANDS`) and are read here by their names (``QueryJob``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, make_dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import tyro

from safe_bc.compare.reproduce import ReproduceConfig
from safe_bc.data.codec import Encoding
from safe_bc.moved import names
from safe_bc.rollout.config import EvalConfig
from safe_bc.run_config import RunConfig
from safe_bc.tasks import DEFAULT_TASK, Task
from safe_bc.tasks.env_config import DEFAULT_RENDERER, Renderer

Flat = tyro.conf.arg(name="")
"""A nested config whose fields are flags without its own prefix (``--selection.eps``, not
``--run.selection.eps``)."""
DEMOS = Path("data/demos")


@dataclass(frozen=True)
class CollectJob:
    """Collect expert demonstrations into Parquet."""

    env: Task = DEFAULT_TASK
    """The testbed: a task of the registry (safe_bc.tasks.TASKS)."""
    renderer: Renderer = DEFAULT_RENDERER
    """CarRacing renderer (raster, the default, is fastest with approximate frames; exact is
    pixel-identical to stock; see results/ablation/renderer/)."""
    out: Path | None = None
    """Dataset folder; None: the task's (data/demos, rehab: data/rehab_demos)."""
    episodes: int | None = None
    """CollectConfig.episodes; None: the task's (5, rehab: 150)."""
    workers: int | None = None
    """CollectConfig.workers; None: its default."""
    seed: int | None = None
    """CollectConfig.seed (the episodes' tracks or patients and the expert's noise); None: its
    default."""
    max_steps: int | None = None
    """CollectConfig.max_steps; None: the env's time limit."""
    encoding: Encoding | None = None
    """CollectConfig.encoding; None: the task's (png for frames, vector for rehab)."""
    quiet: bool = False
    """No progress bar."""


@dataclass(frozen=True)
class DescribeJob:
    """Cost histograms and summary of a demonstration set."""

    demos: Path = DEMOS
    """Demonstration dataset folder."""
    out: Path = Path("results/demos")
    """Where the summary goes."""
    eps: float | None = None
    """Critical-zone width (SelectionConfig.eps); None: the task's (2 px, rehab: 0.05)."""


@dataclass(frozen=True)
class TrainJob:
    """Select T_eps and train one BC agent (a checkpoint)."""

    out: Path
    """Checkpoint folder."""
    demos: Path = DEMOS
    """Demonstration dataset folder."""
    run: Annotated[RunConfig, Flat] = field(default_factory=RunConfig)
    """Selection and behaviour cloning; ``selection.eps`` left unset (not given on the
    command line, or ``None`` through the API) is the demonstrations' task's (``TaskSpec.eps``:
    2 px, rehab: 0.05)."""
    validation_episodes: int = 0
    """Hold out the demonstrations' last N episodes (highest ids) from training and record
    their loss at each log point (curve.parquet's val_loss); d_s and T_eps then come from
    the other episodes. 0: train on every episode (the curve has no validation loss)."""
    quiet: bool = False
    """No progress bar."""


@dataclass(frozen=True)
class HandoverFlags:
    """Deferral at use time, by the names of safe_bc.handover.HandoverConfig's fields (also
    spelled --defer-width, --defer-hold, --defer-lookahead, --defer-hold-on: cli.ALIASES)."""

    width: float | None = None
    """The expert acts wherever the measured cost is within this width of d_s (c_s >= d_s - w,
    cost units; "ask the clinician"), the agent elsewhere; the tables add deferred_steps and
    deferred_share. None: the agent acts everywhere. The measured widths: docs/queries.md."""
    lookahead: int = 0
    """With a width: the zone test reads the cost extrapolated this many steps from its last
    change (a fast-rising cost hands over earlier)."""
    hold: int = 0
    """With a width: the expert also acts on the next this many steps after the last step in
    the zone (a handover that lasts)."""
    hold_on: tuple[str, ...] = ()
    """With a hold: the safety dimensions (the task's names, e.g. front) whose zone test starts
    the hold; empty: any."""

    def __post_init__(self) -> None:
        if self.width is not None and not (math.isfinite(self.width) and self.width >= 0):
            raise ValueError(f"--handover.width must be a finite number >= 0, got {self.width}")
        for name in ("lookahead", "hold"):
            steps = getattr(self, name)
            if steps < 0:
                raise ValueError(f"--handover.{name} must be a number of steps >= 0, got {steps}")
            if steps and self.width is None:
                raise ValueError(
                    f"--handover.{name} needs --handover.width (the zone the expert acts in)"
                )
        if self.hold_on and not self.hold:
            raise ValueError(
                "--handover.hold-on needs --handover.hold (the steps the handover lasts)"
            )

    @property
    def given(self) -> bool:
        """Whether any setting differs from its default (a handover is asked for)."""
        return self != HandoverFlags()


@dataclass(frozen=True)
class EvaluateJob:
    """Evaluate a checkpoint on held-out tracks (or patients)."""

    out: Path
    """Where the episode tables go."""
    checkpoint: Path | None = None
    """A safe-bc train checkpoint (or --recommender)."""
    recommender: Path | None = None
    """A study's recommender folder (results/<study>/recommender): every training seed's agent
    with its handover, on the same tracks (the --handover.* flags do not apply)."""
    recommender_seed: int | None = None
    """With --recommender: evaluate only this training seed's agent."""
    episodes: int = EvalConfig.episodes
    """Held-out episodes, one each (EvalConfig.episodes)."""
    workers: int = EvalConfig.workers
    """Ray actors that run the episodes (EvalConfig.workers)."""
    eval_seed: int = EvalConfig.seed
    """Block of held-out seeds the episodes are drawn from (EvalConfig.seed)."""
    max_steps: int | None = None
    """Step cap per episode (EvalConfig.max_steps); None: the env's."""
    handover: HandoverFlags = field(default_factory=HandoverFlags)
    """Deferral at use time: the expert acts near d_s, the agent elsewhere."""
    quiet: bool = False
    """No progress bar."""

    def __post_init__(self) -> None:
        if self.max_steps is not None and self.max_steps < 1:
            raise ValueError(f"--max-steps must be >= 1 or omitted, got {self.max_steps}")
        if self.episodes < 1:
            raise ValueError(f"--episodes must be >= 1, got {self.episodes}")


@dataclass(frozen=True)
class ExpertJob:
    """Measure the expert on held-out tracks (or patients)."""

    env: Task = DEFAULT_TASK
    """The testbed: a task of the registry (safe_bc.tasks.TASKS)."""
    episodes: int = 20
    """Held-out episodes, one each (EvalConfig.episodes)."""
    workers: int = EvalConfig.workers
    """Ray actors that run the episodes (EvalConfig.workers)."""
    eval_seed: int = 3
    """Block of held-out seeds the episodes are drawn from (EvalConfig.seed)."""
    out: Path = Path("results/expert")
    """Where the tables go."""
    demos: Path | None = None
    """Demonstrations whose worst costs d_s define violations; None: the task's (built if
    absent)."""
    quiet: bool = False
    """No progress bar."""


@dataclass(frozen=True)
class ReproduceJob:
    """Rerun the paper's Table 1 with confidence intervals."""

    config: Annotated[ReproduceConfig, Flat] = field(default_factory=ReproduceConfig)
    """The rerun; ``demos`` and ``out`` not given on the command line are the task's."""
    render_only: bool = False
    """Rebuild the table and figures from the stored per-episode results."""
    quiet: bool = False
    """No progress bars."""


@dataclass(frozen=True)
class CompareJob:
    """Run (or resume) a comparison of a family file."""

    comparison: tyro.conf.Positional[Path]
    """Family file of comparisons, e.g. tune_jobs/compare/improve.py."""
    name: str | None = None
    """The comparison of the file (its address; may be left out where the file has one only;
    a missing or unknown name lists the file's)."""
    render_only: bool = False
    """Rebuild the table from the stored episodes (then its report step, if any)."""
    report_only: bool = False
    """Only rerun the comparison's report step (e.g. the default its table supports) from its
    written table."""
    cell: str | None = None
    """Only train or improve this cell, METHOD:SEED (e.g. selfimitation:1; a start it needs is
    trained first): no evaluation, no table. Cells are independent, so a comparison's cells
    can run in parallel processes or on other machines sharing the output folder; a later run
    without --cell reuses them."""
    workers: int | None = None
    """With --cell: a self-imitation row's rollout actors (0: in this process); its results
    do not depend on it."""
    quiet: bool = False
    """No progress bars."""


@dataclass(frozen=True)
class TuneJob:
    """Run (or resume) a constrained hyper-parameter study.

    Options left unset keep the study file's StudySpec values."""

    study: tyro.conf.Positional[Path]
    """Study file defining STUDY, e.g. tune_jobs/default.py."""
    trials: int | None = None
    """StudySpec.trials."""
    storage: str | None = None
    """StudySpec.storage: Tune storage, a folder or URI (s3://...)."""
    threshold: float | None = None
    """StudySpec.threshold: the safety threshold."""
    max_concurrent: int | None = None
    """StudySpec.max_concurrent: the most trials at once (the study file's None: as many as the
    cluster's CPUs allow, at most a batch)."""
    rollout_workers: int | None = None
    """StudySpec.rollout_workers: evaluation actors per trial."""
    cpus_per_trial: float | None = None
    """StudySpec.cpus_per_trial: CPUs of a trial's own process (fractional allowed)."""
    demos: Path | None = None
    """StudySpec.demos: the demonstration set (a shared path on a cluster)."""
    results: Path | None = None
    """StudySpec.results: outputs go to RESULTS/<study>/."""
    fresh: bool = False
    """Discard a previous run of the study."""
    verbose: bool = False
    """Ray Tune's status table every 30 s instead of one line per finished trial."""
    tracker: Literal["none", "wandb", "mlflow"] = "none"
    """Send every trial's reports to W&B or MLflow too (Ray Tune's own integrations; pip
    install 'safe_bc[wandb]' or 'safe_bc[mlflow]'; where they write: docs/curves.md)."""
    replicates: int | None = None
    """Run N replicates (the study with its seeds shifted) into RESULTS/<study>/replicates/r<k>/
    and write the winners' table RESULTS/<study>/replicates.parquet, .md."""
    more_trials: int = 0
    """Trials added to --trials (or the study file's trials): the same as raising --trials.
    A study that ran (finished or not) resumes, runs the new trials on its Optuna sampler and
    reruns the final phase; no --fresh needed, and a rerun of the same command resumes."""
    set: tuple[str, ...] = ()
    """Any other StudySpec field, FIELD=VALUE, nested configs dotted (base.bc.train.lr=1e-3).
    Applied after the flags above, in order: --set batches=500 sampler_seed=3 env=rehab
    env.max_episode_steps=300 improve.iterations=20; tuples comma-separated, None where
    allowed, env takes a task's name (its env); checked against the fields before the study
    loads (docs/cli.md)."""

    def __post_init__(self) -> None:
        if self.replicates is not None and self.replicates < 1:
            raise ValueError(f"replicates must be >= 1, got {self.replicates}")
        if self.more_trials < 0:
            raise ValueError(f"more_trials must be >= 0, got {self.more_trials}")
        self.spec_overrides()  # a field that does not exist or a value of the wrong type

    def spec_overrides(self) -> list[tuple[str, object]]:
        """``--set``'s ``(dotted StudySpec field, value)`` pairs, in order.

        Raises:
            ValueError: one line naming the override that is no field or a value of the
                wrong type.
        """
        if not self.set:
            return []
        from safe_bc.overrides import parse_override
        from safe_bc.study.spec import StudySpec
        from safe_bc.tasks import task_defaults
        from safe_bc.tasks.env_config import EnvConfig

        whole = {EnvConfig: lambda name: task_defaults(name).env}
        return [parse_override(StudySpec, item, whole) for item in self.set]

    def overrides(self) -> dict[str, object]:
        """The StudySpec fields given."""
        names = ("trials", "storage", "threshold", "max_concurrent", "rollout_workers",
                 "cpus_per_trial", "demos", "results")  # fmt: skip
        return {n: getattr(self, n) for n in names if getattr(self, n) is not None}


@dataclass(frozen=True)
class MethodJob:
    """Run a registered method (safe_bc.methods.METHODS) from a checkpoint; rerun to resume."""

    name: str
    """The method (a key of safe_bc.methods.METHODS)."""
    start: Path
    """A safe-bc train checkpoint."""
    out: Path
    """Run folder (rerun to resume)."""
    config: Any
    """The method's config record (its fields are --config.FIELD flags)."""
    demos: Path | None = None
    """Demonstrations; None: the start's."""


def method_job(config_type: type) -> type:
    """The command-line record of a method whose config is ``config_type``: the fields of
    :class:`MethodJob` but ``name``, ``config`` typed as the method's config record."""

    def arg(kind: Any, doc: str) -> Any:
        return Annotated[kind, tyro.conf.arg(help=doc)]

    fields = [
        ("start", arg(Path, "A safe-bc train checkpoint.")),
        ("out", arg(Path, "Run folder (rerun to resume).")),
        ("config", arg(config_type, "The method's settings."), field(default_factory=config_type)),
        ("demos", arg(Path | None, "Demonstrations; None: the start's."), field(default=None)),
    ]
    return make_dataclass("MethodJob", fields, frozen=True)


@dataclass(frozen=True)
class ExportJob:
    """Export a demonstration set to another format (Minari)."""

    dataset_id: str
    """E.g. safe_bc/carracing-drift-v0; written under $MINARI_DATASETS_PATH (default
    ~/.minari/datasets)."""
    demos: Path = DEMOS
    """Demonstration dataset folder."""
    format: Literal["minari"] = "minari"
    """Target format."""
    author: str | None = None
    """Recorded in the Minari metadata."""
    cost: Literal["critical", "beyond"] = "critical"
    """Which steps DSRL's scalar 'costs' marks 1.0: critical, the critical zone (c_s >= d_s -
    eps in some dimension: the steps nearest the limit); beyond, steps past d_s (none in an
    expert set, whose worst cost is d_s). docs/interop.md."""
    eps: float | None = None
    """The critical zone's width, cost units; None: the task's (TaskSpec.eps)."""


@dataclass(frozen=True)
class RenderJob:
    """Video of an episode with its task's safety readings drawn in (or --paths)."""

    out: Path
    """.mp4, .gif, or .png with --paths."""
    checkpoint: Path | None = None
    """The agent (safe-bc train)."""
    recommender: Path | None = None
    """A study's recommender folder (results/<study>/recommender): its agent with its
    handover; the expert's steps are marked in the video."""
    recommender_seed: int | None = None
    """With --recommender: the training seed of the agent shown; None: its first."""
    expert: bool = False
    """Render the expert instead."""
    paths: bool = False
    """Draw the track map with the driven paths (expert beside agent) to --out."""
    seed: int = 0
    """Track seed."""
    max_steps: int | None = None
    """Step cap per episode; None: the env's."""
    demos: Path | None = None
    """Expert and limits d_s; None: the checkpoint's, else the task's (data/demos)."""
    eps: float | None = None
    """Critical-zone width; None: the checkpoint's, else the task's (2 px)."""
    scale: int | None = None
    """Upscaling of frames; None: render_command's (4)."""
    fps: float | None = None
    """Frames per second of the video; None: render_command's (50)."""
    quiet: bool = False
    """No progress bars (they show on a terminal only)."""

    def __post_init__(self) -> None:
        suffixes = (".png",) if self.paths else (".mp4", ".gif")
        if Path(self.out).suffix.lower() not in suffixes:
            raise ValueError(f"--out must end in {' or '.join(suffixes)}, got {str(self.out)!r}")
        if not Path(self.out).parent.is_dir():
            raise ValueError(f"--out {self.out}: its folder {Path(self.out).parent} does not exist")
        if self.seed < 0:
            raise ValueError(f"seed must be >= 0, got {self.seed}")
        if self.max_steps is not None and self.max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {self.max_steps}")
        if self.scale is not None and self.scale < 1:
            raise ValueError(f"scale must be >= 1, got {self.scale}")
        if self.fps is not None and not 0 < self.fps < float("inf"):
            raise ValueError(f"fps must be finite, > 0, got {self.fps}")


_moved = names(__name__)


def __getattr__(name: str) -> Any:
    """The record of a command from before ``safe-bc method NAME`` by its class name
    (:attr:`safe_bc.methods.MethodCommand.record_name`), from its method's package; an old name
    of :data:`safe_bc.moved.NAMES` (warning once)."""
    from safe_bc.methods import METHOD_COMMANDS

    for command in METHOD_COMMANDS.values():
        if command.record_name == name:
            return command.record()
    return _moved(name)
