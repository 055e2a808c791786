"""Hyper-parameter studies as data: the spec a ``tune_jobs/<name>.py`` file builds, and the pure
pieces around a study run (no Ray): search-space parameters, applying sampled values to a
``RunConfig``, feasibility, the trial table, the winner choice and the Pareto figure.

A study maximises the mean held-out reward subject to two constraints, each ``<= 0`` when met:

* ``constraint_safety``: the safety mean must reach the expert's (on its demonstrations),
  ``threshold - safety_mean``, and with ``safety_constraint="per_dim"`` also every
  dimension's mean its own expert mean (the largest gap counts);
* ``constraint_violation``: the share of steps beyond the expert's limit ``d_s``
  (``violation_rate``) must not exceed ``violation_tolerance``.

``constraint`` is the larger of the two (``<= 0``: feasible).
The Ray side (``safe_bc.study.run``) samples parameters with Optuna, runs the trials
and hands the finished table to :func:`choose_winner`.

>>> spec = StudySpec("demo", {"selection.alpha": Float(0.0, 1.0), "bc.network.channels":
...     Choice(((8, 16, 16), (16, 32, 32)))})
>>> cfg = apply_params(spec.base, {"selection.alpha": 0.3, "bc.network.channels": "8-16-16"})
>>> cfg.selection.alpha, cfg.bc.network.channels
(0.3, (8, 16, 16))
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields, is_dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import pandas as pd

from safe_bc.config_file import run_config_file
from safe_bc.handover import HandoverConfig
from safe_bc.methods import METHODS, MethodSpec
from safe_bc.methods.improve.config import ImproveConfig
from safe_bc.methods.queries.config import QueryConfig
from safe_bc.methods.selfimprove.config import SelfImproveConfig
from safe_bc.methods.stages import stage_metrics, stage_of
from safe_bc.metrics import pareto_mask  # noqa: F401 (named here before)
from safe_bc.run_config import RunConfig
from safe_bc.tasks.env_config import EnvConfig

if TYPE_CHECKING:
    from safe_bc.tasks import TaskSpec

Primitive = bool | int | float | str
Baseline = Literal["same_network", "default"]
SafetyConstraint = Literal["combined", "per_dim"]


@dataclass(frozen=True)
class Float:
    """A real parameter sampled from ``[low, high]``."""

    low: float
    """Smallest value."""
    high: float
    """Largest value."""
    log: bool = False
    """Sample uniformly in log space (``low`` must be > 0)."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.low) and math.isfinite(self.high) and self.low <= self.high):
            raise ValueError(f"Float needs finite low <= high, got {self.low}, {self.high}")
        if self.log and self.low <= 0:
            raise ValueError(f"Float(log=True) needs low > 0, got {self.low}")

    def bounds(self) -> tuple[float, float]:
        """The extreme values (for validation)."""
        return self.low, self.high


@dataclass(frozen=True)
class Int:
    """An integer parameter sampled from ``[low, high]``."""

    low: int
    """Smallest value."""
    high: int
    """Largest value."""
    step: int = 1
    """Spacing of the values (``low, low + step, ...``)."""
    log: bool = False
    """Sample uniformly in log space (``low`` must be >= 1, ``step`` 1)."""

    def __post_init__(self) -> None:
        if self.low > self.high or self.step < 1:
            raise ValueError(f"Int needs low <= high and step >= 1, got {self}")
        if self.log and (self.low < 1 or self.step != 1):
            raise ValueError(f"Int(log=True) needs low >= 1 and step 1, got {self}")

    def bounds(self) -> tuple[int, int]:
        """The extreme values (for validation)."""
        return self.low, self.high


@dataclass(frozen=True)
class Choice:
    """A categorical parameter. Options are ``bool``/``int``/``float``/``str`` or tuples of
    ints (e.g. conv channels); tuples travel as labels like ``"16-32-32"`` (Optuna only
    accepts primitive categories) and are decoded by :func:`apply_params`."""

    options: tuple[Any, ...]
    """The values to choose from (at least one)."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "options", tuple(self.options))
        if not self.options:
            raise ValueError("Choice needs at least one option")
        labels = self.labels()
        if len(set(labels)) != len(labels):
            raise ValueError(f"Choice options must be distinct, got {self.options}")

    def labels(self) -> tuple[Primitive, ...]:
        """The options as Optuna-safe primitives."""
        return tuple(encode_value(o) for o in self.options)

    def bounds(self) -> tuple[Primitive, ...]:
        """Every option (for validation)."""
        return self.labels()


Param = Float | Int | Choice
"""One dimension of a search space."""


def encode_value(value: Any) -> Primitive:
    """A config value as a primitive: tuples of ints become ``"a-b-c"`` (``()`` is ``"-"``).

    >>> encode_value((16, 32, 32)), encode_value(()), encode_value(0.5)
    ('16-32-32', '-', 0.5)
    """
    if isinstance(value, tuple | list):
        if not all(isinstance(v, int) and not isinstance(v, bool) for v in value):
            raise ValueError(f"tuple options must hold ints, got {value!r}")
        return "-".join(str(v) for v in value) if value else "-"
    if isinstance(value, bool | int | float | str):
        return value
    raise ValueError(f"unsupported option type {type(value).__name__}: {value!r}")


def _coerce(current: Any, value: Any, name: str) -> Any:
    """``value`` in the type of the field's ``current`` value."""
    if isinstance(current, tuple) and isinstance(value, str):
        return () if value == "-" else tuple(int(v) for v in value.split("-"))
    if isinstance(current, bool):
        if not isinstance(value, bool | np.bool_):
            raise ValueError(f"{name} is a bool, got {value!r}")
        return bool(value)
    if isinstance(current, int):
        if float(value) != int(value):
            raise ValueError(f"{name} is an integer, got {value!r}")
        return int(value)
    if isinstance(current, float):
        return float(value)
    return value.item() if isinstance(value, np.generic) else value


def _field_value(obj: Any, parts: Sequence[str], name: str) -> Any:
    """The current value of the dotted field ``parts`` of ``obj``."""
    for head in parts:
        if not is_dataclass(obj) or head not in {f.name for f in fields(obj)}:
            raise ValueError(
                f"unknown parameter {name!r}: no field {head!r} in {type(obj).__name__}"
            )
        obj = getattr(obj, head)
    return obj


def check_param_type(name: str, param: Any, current: Any) -> None:
    """``param`` can only give values of the type of the field it searches (its ``current``
    value): a ``Float`` over an integer field, or a ``Choice`` of text for a number, is refused
    here, before any trial runs, instead of failing (or silently converting) in a trial.

    >>> check_param_type("bc.train.batch_size", Float(16, 64), 32)
    Traceback (most recent call last):
    ...
    ValueError: space['bc.train.batch_size'] is a Float, but the field is an int (32): use Int(...) or Choice of ints
    """  # noqa: E501

    def refuse(what: str, use: str) -> ValueError:
        kind = type(current).__name__
        return ValueError(
            f"space[{name!r}] is {what}, but the field is {_article(kind)} ({current!r}): use {use}"
        )

    def number(v: Any) -> bool:
        return isinstance(v, int | float) and not isinstance(v, bool)

    if current is None:
        return  # an optional field: any type its config accepts
    if isinstance(current, bool):
        if not (isinstance(param, Choice) and all(isinstance(o, bool) for o in param.options)):
            raise refuse(_article(type(param).__name__), "Choice((False, True))")
    elif isinstance(current, int):
        if isinstance(param, Float):
            raise refuse("a Float", "Int(...) or Choice of ints")
        if isinstance(param, Choice) and not all(
            isinstance(o, int) and not isinstance(o, bool) for o in param.options
        ):
            raise refuse(f"a Choice of {param.options!r}", "Choice of ints")
    elif isinstance(current, float):
        if isinstance(param, Choice) and not all(number(o) for o in param.options):
            raise refuse(f"a Choice of {param.options!r}", "Float(...) or Choice of numbers")
    elif isinstance(current, tuple) and not (
        isinstance(param, Choice) and all(isinstance(o, tuple | list) for o in param.options)
    ):
        raise refuse(_article(type(param).__name__), "Choice of tuples of ints")
    elif isinstance(current, str) and not (
        isinstance(param, Choice) and all(isinstance(o, str) for o in param.options)
    ):
        raise refuse(_article(type(param).__name__), "Choice of strings")


def _article(word: str) -> str:
    return f"an {word}" if word[:1].lower() in "aeiou" else f"a {word}"


def _replace_path(obj: Any, parts: Sequence[str], value: Any, name: str) -> Any:
    head, rest = parts[0], parts[1:]
    if not is_dataclass(obj) or head not in {f.name for f in fields(obj)}:
        raise ValueError(f"unknown parameter {name!r}: no field {head!r} in {type(obj).__name__}")
    current = getattr(obj, head)
    new = _replace_path(current, rest, value, name) if rest else _coerce(current, value, name)
    return replace(obj, **{head: new})


def split_params(params: Mapping[str, Any]) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
    """``(run_params, {stage: stage_params})``: the ``RunConfig`` keys, and each stage's keys
    (:data:`safe_bc.methods.METHODS`) with its prefix removed.

    >>> split_params({"selection.alpha": 0.5, "improve.cost_margin": 0.1})
    ({'selection.alpha': 0.5}, {'improve': {'cost_margin': 0.1}})
    """
    run: dict[str, Any] = {}
    stages: dict[str, dict[str, Any]] = {}
    for key, value in params.items():
        name = stage_of(key)
        if name is None:
            run[key] = value
        else:
            stages.setdefault(name, {})[key.removeprefix(METHODS[name].prefix)] = value
    return run, stages


def apply_stage_params(base: Any, prefix: str, params: Mapping[str, Any]) -> Any:
    """``base`` (a stage's config) with each parameter (``"cost_margin"``, no prefix) set.

    Raises:
        ValueError: an unknown field, or a value the config rejects.
    """
    config = base
    for name, value in params.items():
        config = _replace_path(config, name.split("."), value, prefix + name)
    return config


def apply_params(base: RunConfig, params: Mapping[str, Any]) -> RunConfig:
    """``base`` with each dotted parameter (``"selection.eps"``, ``"bc.train.lr"``) set.

    Raises:
        ValueError: an unknown path, or a value the config rejects.
    """
    config = base
    for name, value in params.items():
        config = _replace_path(config, name.split("."), value, name)
    return config


@dataclass(frozen=True)
class StudySpec:
    """A constrained hyper-parameter study: search space, budget, threshold, resources."""

    name: str
    """Study name: the Tune experiment name and the output folder ``results/<name>/``."""
    space: Mapping[str, Param]
    """Search space keyed by dotted ``RunConfig`` paths: ``selection.eps``, ``selection.alpha``,
    ``selection.rest``, ``bc.network.channels``, ``bc.network.hidden``, ``bc.train.lr``,
    ``bc.train.batch_size``, ``bc.preprocess.frame_stack``, ``bc.preprocess.grayscale``, ..."""
    base: RunConfig | None = None
    """Values of everything not searched (``bc.train.seed`` is every trial's training seed).
    ``None``: ``RunConfig()``. Its ``selection.eps`` left unset (``None``, the default) is the
    task's (``TaskSpec.eps``, in its cost's units), resolved when the spec is made (a spec made
    by ``replace`` keeps the resolved value: pass a base without eps with another ``env``)."""
    trials: int = 20
    """Number of trials (``--trials`` overrides)."""
    max_concurrent: int | None = None
    """Most trials running at once (``--max-concurrent``): how many run at once, never which
    ones (with :attr:`batch_size`). ``None``: as many as the cluster's CPUs allow, resolved
    when the tuning loop starts (:meth:`concurrency`: the cluster's CPUs // a trial's CPUs, at
    most :attr:`batch_size`); an integer caps that."""
    batch_size: int | None = 2
    """Trials suggested together: every suggestion of a batch is made before any of its
    results is told to the sampler, the results are told in trial order once the whole batch
    is in, and the screening compares a trial with the earlier batches only; so the same
    study file gives the same trials whatever :attr:`max_concurrent` is (a trial of the next
    batch starts only when the whole batch has finished: slots idle while the slowest trial
    of a batch runs). ``None``: results are told as trials finish (no waiting, but the
    trials then depend on the order in which concurrent trials finish)."""
    batches: int = 2000
    """Per-trial budget: training batches (overrides ``base.bc.train.batches``)."""
    eval_episodes: int = 10
    """Per-trial budget: held-out evaluation episodes (tracks) of a trial that survives the
    screening."""
    screen_episodes: int = 3
    """The cheap first evaluation: after this many of its ``eval_episodes`` tracks a trial
    reports, and successive halving (``BatchHalving``; Tune's ASHA without batches) stops the
    trials whose screened score (the objective, minus a large penalty when a constraint is
    broken) is in the lower half of the earlier ones; 0 (or ``>= eval_episodes``) evaluates
    every trial on all tracks."""
    max_steps: int | None = None
    """Step cap per evaluation episode (``None``: the env's time limit)."""
    eval_seed: int = 1
    """Held-out seed block of the trials' evaluations."""
    final_episodes: int = 50
    """Fresh held-out tracks of the final phase per candidate: split evenly across its
    ``final_train_seeds`` (each seed on its own tracks, rounded up), and the same tracks for
    plain BC (same seeds) and the expert."""
    final_candidates: int = 3
    """Top feasible trials (by trial reward) retrained and re-evaluated in the final phase;
    the closest infeasible ones fill in when fewer are feasible."""
    final_train_seeds: int = 3
    """Training seeds per candidate in the final phase: the trial's own seed (its checkpoint,
    which a rerun reproduces bit for bit) and the next ones."""
    final_seed: int = 2
    """Held-out seed block of the re-evaluation (must differ from ``eval_seed``)."""
    final_workers: int | None = None
    """Training and evaluation actors of the final phase; ``None``: one per CPU of the
    cluster (0: in the driver process)."""
    baseline: Baseline = "same_network"
    """The alpha = 0 baseline: plain BC with the winner's preprocessing, network and training
    settings (``"same_network"``) or with ``base``'s (``"default"``)."""
    threshold: float | None = None
    """Safety threshold; ``None``: the expert's safety mean on the demonstrations,
    ``combined(demos.safety[demos.scored]).mean()``."""
    critical_eps: float | None = None
    """Width of the critical zone behind ``critical_share`` (fixed, so trials compare);
    ``None``: the task's ``eps`` (``TaskSpec.eps``), resolved when the spec is made."""
    safety_constraint: SafetyConstraint = "combined"
    """``"combined"``: safety mean (smallest distance) >= the expert's; ``"per_dim"``: that and
    every dimension's mean >= the expert's mean in that dimension (stricter). The default is
    ``"combined"`` because on CarRacing no policy of Table 1 (8 seeds x 20 fresh tracks,
    ``results/table1_episodes.parquet``), not even the expert, reaches the demonstrations'
    mean on every side: the left and right distances add up to the road's width, so a policy
    further from the grass on one side is closer on the other (expert: left 7.70 >= 7.67,
    right 7.65 < 7.81). The per-dimension limits still bind step by step: a violation is a
    step beyond ``d_s`` in any dimension."""
    violation_tolerance: float = 0.0
    """Largest allowed share of evaluated steps beyond the expert's limit ``d_s`` (the point
    constraint, without :attr:`violation_bound`)."""
    violation_bound: float | None = None
    """With a confidence (e.g. 0.95), the violation constraint is a bound instead of a point
    estimate: the one-sided Clopper-Pearson upper confidence bound on the share of episodes
    that reach a state beyond ``d_s`` (``any_violation``, an episode ending beyond it
    included; :func:`safe_bc.metrics.clopper_pearson_upper`, episodes taken as independent)
    must not exceed :attr:`violation_share_limit`; the final phase applies the same rule to
    its fresh episodes. ``None`` (default, as before): the share of steps beyond ``d_s`` must
    not exceed :attr:`violation_tolerance`."""
    violation_share_limit: float = 0.2
    """Largest allowed upper bound on the share of episodes beyond ``d_s`` (with
    :attr:`violation_bound`). Zero violations in ``n`` episodes bound the share at about
    ``3 / n`` (95%), so a trial needs ``n >~ 3 / limit`` episodes to be feasible at all (15
    at 0.2: e.g. one seed x 15 tracks, or 2 seeds x 10)."""
    train_seeds: int = 1
    """Training seeds per trial: ``base.bc.train.seed`` and the next ones, each trained and
    evaluated on the trial's same tracks (a crossed seeds x tracks design); the trial's
    metrics are means over all its episodes. 1 (default): one seed, as before."""
    reward_bound: float | None = None
    """With a confidence (e.g. 0.9), the objective is a one-sided lower confidence bound on the
    trial's mean reward (``reward_lcb``: crossed bootstrap over its seeds and tracks with a
    fixed bootstrap seed, :func:`safe_bc.metrics.lower_bound_crossed`); use it with
    ``train_seeds >= 2``. ``None`` (default): the mean reward."""
    demos: Path = Path("data/demos")
    """Demonstration set (built with ``ensure_demos`` if absent); a shared path on a cluster."""
    validation_episodes: int | Literal["task"] = "task"
    """Demonstration episodes held out for the learning curves' validation loss: the study
    collects them with its own collector on tracks of their own (collection seed
    :data:`safe_bc.seeds.VALIDATION_SEED`) into ``<demos>_validation/``, never trains on them,
    and every trial's and final candidate's curve (``bc/curve.parquet``, TensorBoard
    ``bc/val_loss``) records the loss on them at each log point. The loss reads no random
    number and changes no weight, so the study's numbers are the same with any value.
    ``"task"`` (default): the task's (``TaskSpec.validation_episodes``, chosen by
    ``results/validation_size/``), resolved when the spec is made; 0: training loss only.
    :attr:`validation_demos` replaces the collected set."""
    validation_demos: Path | None = None
    """Another demonstration set of the same task (``safe-bc collect`` with other seeds) to
    compute the validation loss on instead of the collected one; ``None``: the set
    :attr:`validation_episodes` collects (none at 0)."""
    storage: str = "results/ray"
    """Tune storage: a local folder (made absolute), a shared file system or an ``s3://`` URI."""
    results: Path = Path("results")
    """Outputs go to ``results/<name>/``."""
    env: EnvConfig = field(default_factory=EnvConfig)
    """Evaluation environment (must be the demonstrations' task)."""
    rollout_workers: int = 0
    """Evaluation actors per trial (0: evaluate in the trial's own process)."""
    trial_envs: int = 1
    """Episodes a trial's evaluation steps in lockstep per process (``envs_per_worker`` of
    :func:`safe_bc.distributed.evaluate.evaluate_policies`): its tracks are dealt to fixed
    groups of this many in seed order, each group stepped with one batched forward pass
    (:attr:`safe_bc.rollout.evaluate.EvalConfig.lockstep_forward`), so a trial's episodes depend on
    this number and the machine type, never on how many trials or workers run. 1 (default):
    one env at a time, the one-env path (for given weights, the same episodes on any CPU).
    ``make bench``'s eval case measures the gain (raster, 4 envs in lockstep with one batched
    forward against 1 env)."""
    cpus_per_trial: float = 1.0
    """CPUs reserved for a trial's own process (fractional allowed). Training does not follow
    it: every trial trains with ``base.bc.train.num_threads`` torch threads (1 when unset),
    recorded in its checkpoint's run config, so a rerun with other resources gives the same
    weights."""
    cpus_per_worker: float = 1.0
    """CPUs reserved per rollout worker of a trial."""
    max_failures: int = 2
    """Retries of a failed trial (it resumes from its post-training checkpoint)."""
    optuna_storage: str | None = None
    """Optuna storage URL the study's Optuna trials (parameters, objective, constraint values,
    Tune trial ids) are copied to after every batch, for Optuna's own tools
    (``optuna.load_study``, ``optuna-dashboard``): ``None``, a SQLite file beside the tables,
    ``results/<name>/optuna.db``; an RDB URL (``postgresql://...``) for a cluster. The
    searcher inside Tune's experiment stays the source of truth (checkpointed and resumed
    with the study); this is its copy, rewritten whole each time."""
    sampler_seed: int = 0
    """Seed of Optuna's TPE sampler."""
    startup_trials: int = 8
    """Random trials before TPE starts modelling."""
    improve: ImproveConfig | None = None
    """Optional improvement stage (:mod:`safe_bc.methods.improve`, constrained RL beyond the
    expert):
    with a config, every trial, after its BC training, improves its agent from there (the
    trained net is the start; ``seed`` is replaced by the training seed) and the *improved*
    agent is what the trial's evaluation, constraints and objective measure, and what the
    final phase retrains (BC, then improvement, per seed) and re-evaluates; plain BC and the
    expert stay the references. Its fields are searchable as ``improve.<field>`` keys of
    :attr:`space` (e.g. ``improve.cost_margin``, ``improve.anchor_coef``). ``None``: no
    improvement (imitation only)."""
    queries: QueryConfig | None = None
    """Optional critical-zone query stage (:mod:`safe_bc.methods.queries`, interactive imitation):
    every trained agent is rolled out, the expert labels the visited states in the critical
    zone, and the agent is retrained on demonstrations plus labels, for ``rounds`` rounds.
    Searchable as ``queries.<field>`` keys. ``None``: no queries."""
    handover: HandoverConfig | Literal["task"] | None = "task"
    """The critical-zone handover every agent of the study is evaluated with (trials, final
    candidates, the certification): the agent acts, the expert where the cost is near ``d_s``
    (:class:`safe_bc.handover.HandoverConfig`). The study then searches for the best
    *recommender* (agent plus handover), its deferred share is a constraint
    (:attr:`deferred_share_limit`), and the final phase also reports the winner's agent alone.
    ``"task"`` (default): the task's (``TaskSpec.handover``; none where the task has none
    measured), resolved when the spec is made. ``None``: agents act alone (plain BC is always
    evaluated alone)."""
    deferred_share_limit: float = 1.0
    """Largest allowed mean share of an episode's steps on which the expert acted (a
    constraint with :attr:`handover`; 1: none)."""
    certify_episodes: int = 0
    """Fresh episodes of the winner's certification after the final phase: the winner (with
    its handover, and alone) and the expert on their own block :attr:`certify_seed`, split
    evenly over the final training seeds; the certificate (crossings and their one-sided
    bound, reward against the expert, deferred share) is made from these episodes only, which
    did not choose the winner. 0: no certification (the final phase's episodes certify)."""
    certify_seed: int = 3
    """Held-out seed block of the certification (must differ from the trials' and the final
    phase's)."""
    collect: Any = None
    """The demonstration collection the study expects at :attr:`demos` (a
    :class:`safe_bc.rollout.collect.CollectConfig`); ``None``: the task's default collection. It is
    built when absent and a set made with other settings is refused before any work."""
    selfimprove: SelfImproveConfig | None = None
    """Optional self-imitation stage (:mod:`safe_bc.methods.selfimprove`, expert iteration inside
    ``d_s``): every trained agent's own rollouts, pushed to explore, are kept where they stay
    inside ``d_s`` minus a margin and beat the unperturbed run, and the agent is retrained on
    demonstrations plus kept data, for ``rounds`` rounds; a round's agent is kept only when it
    passes the keep rule. Searchable as ``selfimprove.<field>`` keys. ``None``: off."""
    stage_configs: Mapping[str, Any] = field(default_factory=dict)
    """Configs of further registered methods (:data:`safe_bc.methods.METHODS`) run as stages,
    by method name (the built-in ones have their own fields above); searchable as
    ``<name>.<field>`` keys. Empty: none."""

    def __post_init__(self) -> None:
        if not self.name or not self.name.replace("_", "").replace("-", "").isalnum():
            raise ValueError(f"study name must be letters, digits, - or _, got {self.name!r}")
        self._take_task_defaults()
        object.__setattr__(self, "space", dict(self.space))
        object.__setattr__(self, "stage_configs", dict(self.stage_configs))
        for name, config in self.stage_configs.items():
            if name not in METHODS or name in {f.name for f in fields(self)}:
                own = name in METHODS
                raise ValueError(
                    f"stage_configs[{name!r}]: "
                    + (f"set StudySpec({name}=...)" if own else f"no method {name!r} is registered")
                )
            METHODS[name].check(config)
        object.__setattr__(self, "demos", Path(self.demos))
        object.__setattr__(self, "results", Path(self.results))
        object.__setattr__(self, "storage", str(self.storage))
        self._check_sizes()
        self._check_bars_and_seeds()
        self._check_space()

    def _take_task_defaults(self) -> None:
        """The task's critical-zone width (``selection.eps`` of the base and
        ``critical_eps``), handover and validation episodes where the spec leaves them unset;
        one line naming the env when no registered task has it."""
        from safe_bc.tasks import with_task_eps

        base = RunConfig() if self.base is None else self.base
        unset = base.selection.eps is None or self.critical_eps is None
        if not unset and "task" not in (self.handover, self.validation_episodes):
            object.__setattr__(self, "base", base)
            return
        task = self.task()
        if self.validation_episodes == "task":
            object.__setattr__(self, "validation_episodes", task.validation_episodes)
        object.__setattr__(self, "base", with_task_eps(base, self.env.env_id))
        if self.critical_eps is None:
            object.__setattr__(self, "critical_eps", float(task.eps))
        if self.handover == "task":
            object.__setattr__(self, "handover", task.handover)

    def _check_sizes(self) -> None:
        """Counts, batch sizes and workers: integers in range."""
        if self.max_concurrent is not None and (
            isinstance(self.max_concurrent, bool)
            or not isinstance(self.max_concurrent, int)
            or self.max_concurrent < 1
        ):
            raise ValueError(
                f"max_concurrent must be an integer >= 1 or None, got {self.max_concurrent!r}"
            )
        for key, value in (
            ("trials", self.trials),
            ("batches", self.batches),
            ("eval_episodes", self.eval_episodes),
            ("final_episodes", self.final_episodes),
            ("trial_envs", self.trial_envs),
        ):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{key} must be an integer >= 1, got {value!r}")
        if self.batch_size is not None and (
            isinstance(self.batch_size, bool)
            or not isinstance(self.batch_size, int)
            or self.batch_size < 1
        ):
            raise ValueError(f"batch_size must be an integer >= 1 or None, got {self.batch_size!r}")
        for key in ("final_candidates", "final_train_seeds"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{key} must be an integer >= 1, got {value!r}")
        if self.final_workers is not None and self.final_workers < 0:
            raise ValueError(f"final_workers must be >= 0 or None, got {self.final_workers}")
        if self.screen_episodes < 0:
            raise ValueError(f"screen_episodes must be >= 0, got {self.screen_episodes}")
        v = self.validation_episodes
        if isinstance(v, bool) or not isinstance(v, int) or v < 0:
            raise ValueError(f"validation_episodes must be an integer >= 0 or 'task', got {v!r}")

    def _check_bars_and_seeds(self) -> None:
        """Constraints, confidences and shares in range; the seeds of the trials, the final
        phase and the certificate distinct; the handover and the rest of the settings valid."""
        if self.safety_constraint not in ("combined", "per_dim"):
            raise ValueError(
                f"safety_constraint must be 'combined' or 'per_dim', got {self.safety_constraint!r}"
            )
        if not (math.isfinite(self.violation_tolerance) and 0 <= self.violation_tolerance <= 1):
            raise ValueError(
                f"violation_tolerance must be in [0, 1], got {self.violation_tolerance!r}"
            )
        for key in ("violation_bound", "reward_bound"):
            value = getattr(self, key)
            if value is not None and not (0.5 <= value < 1):
                raise ValueError(f"{key} must be a confidence in [0.5, 1) or None, got {value!r}")
        if not (math.isfinite(self.violation_share_limit) and 0 <= self.violation_share_limit <= 1):
            raise ValueError(
                f"violation_share_limit must be in [0, 1], got {self.violation_share_limit!r}"
            )
        if (
            isinstance(self.train_seeds, bool)
            or not isinstance(self.train_seeds, int)
            or (self.train_seeds < 1)
        ):
            raise ValueError(f"train_seeds must be an integer >= 1, got {self.train_seeds!r}")
        if not (math.isfinite(self.critical_eps) and self.critical_eps >= 0):
            raise ValueError(f"critical_eps must be >= 0, got {self.critical_eps!r}")
        for key in ("rollout_workers", "max_failures", "startup_trials"):
            if getattr(self, key) < 0:
                raise ValueError(f"{key} must be >= 0, got {getattr(self, key)}")
        if self.max_steps is not None and self.max_steps < 1:
            raise ValueError(f"max_steps must be >= 1 or None, got {self.max_steps}")
        if self.eval_seed == self.final_seed:
            raise ValueError(f"final_seed must differ from eval_seed (both {self.eval_seed})")
        if self.certify_episodes and self.certify_seed in (self.eval_seed, self.final_seed):
            raise ValueError(
                f"certify_seed {self.certify_seed} must differ from eval_seed and final_seed"
            )
        if isinstance(self.certify_episodes, bool) or self.certify_episodes < 0:
            raise ValueError(f"certify_episodes must be >= 0, got {self.certify_episodes!r}")
        if not (math.isfinite(self.deferred_share_limit) and 0 <= self.deferred_share_limit <= 1):
            raise ValueError(
                f"deferred_share_limit must be in [0, 1], got {self.deferred_share_limit!r}"
            )
        if self.handover is not None and not isinstance(self.handover, HandoverConfig):
            raise ValueError(f"handover must be a HandoverConfig or None, got {self.handover!r}")
        if not (self.cpus_per_trial > 0 and self.cpus_per_worker > 0):
            raise ValueError("cpus_per_trial and cpus_per_worker must be > 0")
        if self.baseline not in ("same_network", "default"):
            raise ValueError(f"baseline must be 'same_network' or 'default', got {self.baseline!r}")
        if self.threshold is not None and not math.isfinite(self.threshold):
            raise ValueError(f"threshold must be finite or None, got {self.threshold}")

    def _check_space(self) -> None:
        """Every search key names a field of the base config or of a stage the study runs, and
        every bound or option of it builds a valid config."""
        for name, param in self.space.items():
            if not isinstance(param, Float | Int | Choice):
                raise ValueError(f"space[{name!r}] must be Float, Int or Choice, got {param!r}")
            stage = stage_of(name)
            if stage is not None and self.stage_base(stage) is None:
                raise ValueError(
                    f"space[{name!r}] searches the {stage} stage, but the study has none: "
                    f"set StudySpec({stage}=...)"
                )
            if stage is None:
                owner, path = self.base, name
            else:
                owner = self.stage_base(stage)
                path = name.removeprefix(METHODS[stage].prefix)
            check_param_type(name, param, _field_value(owner, path.split("."), name))
            for value in param.bounds():  # every option / bound builds a valid config
                if stage is None:
                    apply_params(self.base, {name: value})
                else:
                    self.stage_config(stage, {name: value}, seed=0)

    @property
    def screens(self) -> bool:
        """Whether trials are screened on ``screen_episodes`` tracks first."""
        return 0 < self.screen_episodes < self.eval_episodes

    @property
    def trial_cpus(self) -> float:
        """CPUs one trial reserves: its own process and its rollout workers."""
        return self.cpus_per_trial + self.rollout_workers * self.cpus_per_worker

    def concurrency(self, cluster_cpus: float) -> int:
        """Trials the tuning loop runs at once on a cluster of ``cluster_cpus`` CPUs: as many as
        fit (``cluster_cpus // trial_cpus``, at least 1), at most :attr:`batch_size` (a batch is
        the most that can run at once), :attr:`max_concurrent` and :attr:`trials`. It decides
        how many trials run at once, never which: nothing that determines the trials reads it.

        >>> spec = StudySpec("s", {}, trials=16, batch_size=8)
        >>> spec.concurrency(2), spec.concurrency(16), spec.concurrency(0.5)
        (2, 8, 1)
        >>> replace(spec, max_concurrent=4).concurrency(16)
        4
        >>> replace(spec, cpus_per_trial=0.5).concurrency(2)  # 4 logical slots on 2 CPUs
        4
        """
        fit = math.floor(cluster_cpus / self.trial_cpus + 1e-9)
        caps = [self.trials, max(fit, 1)]
        caps += [c for c in (self.batch_size, self.max_concurrent) if c is not None]
        return int(min(caps))

    def final_tracks_per_seed(self) -> int:
        """Fresh tracks each training seed of a final candidate is evaluated on."""
        return -(-self.final_episodes // self.final_train_seeds)

    @property
    def objective(self) -> str:
        """The trial metric the search maximises: ``reward_lcb`` with :attr:`reward_bound`,
        else ``reward_mean``."""
        return "reward_lcb" if self.reward_bound is not None else OBJECTIVE

    def trial_seeds(self) -> list[int]:
        """The training seeds of every trial (``base.bc.train.seed`` and the next ones)."""
        return [self.base.bc.train.seed + i for i in range(self.train_seeds)]

    @property
    def params(self) -> tuple[str, ...]:
        """The searched parameter names, in space order."""
        return tuple(self.space)

    def task(self) -> TaskSpec:
        """The registered task of :attr:`env` (its defaults, words and metrics)."""
        from safe_bc.tasks import task_defaults, task_of

        return task_defaults(task_of(self.env.env_id))

    def run_config(self, params: Mapping[str, Any], num_threads: int | None = None) -> RunConfig:
        """The trial's ``RunConfig``: ``base`` + sampled ``params`` (the ``RunConfig`` keys;
        stage keys such as ``improve.*`` go to :meth:`stage_config`) + the batch budget."""
        cfg = apply_params(self.base, split_params(params)[0])
        train = replace(cfg.bc.train, batches=self.batches, num_threads=num_threads)
        return replace(cfg, bc=replace(cfg.bc, train=train))

    def stages(self) -> list[MethodSpec]:
        """The stages this study runs after training (the registered methods,
        :data:`safe_bc.methods.METHODS`, whose config it sets), in registry order."""
        return [m for n, m in METHODS.items() if self.stage_base(n) is not None]

    def stage_base(self, stage: str) -> Any:
        """The study's config of ``stage`` before any search parameter (its own field for the
        built-in methods, else :attr:`stage_configs`); ``None``: the stage is off."""
        if stage in {f.name for f in fields(self)}:
            return getattr(self, stage)
        return self.stage_configs.get(stage)

    def stage_config(self, stage: str, params: Mapping[str, Any], seed: int) -> Any:
        """The trial's settings of ``stage``: its config field + the sampled ``<stage>.*``
        ``params``, with ``seed`` (the BC training seed); ``None`` when the study has none."""
        base = self.stage_base(stage)
        if base is None:
            return None
        own = split_params(params)[1].get(stage, {})
        return replace(apply_stage_params(base, METHODS[stage].prefix, own), seed=seed)

    def baseline_config(self, winner: RunConfig) -> RunConfig:
        """The alpha = 0 baseline (plain BC: ``rest="all"``) for the re-evaluation."""
        ref = winner if self.baseline == "same_network" else self.run_config({})
        sel = replace(ref.selection, alpha=0.0, rest="all")
        return replace(ref, selection=sel)

    def summary(self) -> dict[str, Any]:
        """JSON-able description (stored with every output)."""
        space = {k: {"type": type(p).__name__, **_param_dict(p)} for k, p in self.space.items()}
        out = {
            f.name: getattr(self, f.name)
            for f in fields(self)
            if f.name not in ("space", "stage_configs")
        }
        out["base"] = self.base.to_dict()
        out["env"] = {f.name: getattr(self.env, f.name) for f in fields(self.env)}
        out["demos"], out["results"] = str(self.demos), str(self.results)
        out["space"] = space
        out["handover"] = None if self.handover is None else self.handover.to_dict()
        out["collect"] = None if self.collect is None else _config_json(self.collect)
        for name in METHODS:
            config = self.stage_base(name)
            if name in out or config is not None:  # (further methods only when set)
                out[name] = None if config is None else config.to_dict()
        return out


RESOURCE_FIELDS = frozenset(
    {
        "max_concurrent",
        "cpus_per_trial",
        "cpus_per_worker",
        "rollout_workers",
        "final_workers",
        "max_failures",
        "storage",
        "results",
        "optuna_storage",
        "demos",
    }
)
"""``StudySpec`` fields that change where and how fast the study runs, never a trial's or the
final phase's numbers: a rerun may change them (``storage`` is compared as the experiment's
path, ``experiment_path``; the demonstrations by their digest, wherever they lie)."""


CURVE_FIELDS = frozenset({"validation_episodes", "validation_demos"})
"""``StudySpec`` fields that change what the learning curves show, never a trial's or the final
phase's numbers (the validation loss reads no random number and changes no weight): outside
the settings a resume compares, as the resource fields are; the validation set a study used is
compared by its digest (``validation_digest`` of ``study.json``)."""


def settings_of(summary: Mapping[str, Any]) -> dict[str, Any]:
    """The part of ``StudySpec.summary()`` that shapes the trials and the final phase, as JSON
    values (what ``study.json`` keeps and a resume compares)."""
    kept = {k: v for k, v in summary.items() if k not in RESOURCE_FIELDS | CURVE_FIELDS}
    return json.loads(json.dumps(kept, sort_keys=True, default=str))


def subset_warnings(spec: StudySpec, demos: Any) -> list[str]:
    """One line for each eps the study can train with (the base's, or the searched range's
    bounds and options) whose ``T_eps`` on ``demos`` holds no scored row or every one, so that
    alpha cannot act (:func:`safe_bc.selection.improper_subset_message`); none for a study
    whose base selection is not the alpha mix."""
    from safe_bc.selection import improper_subset_message, select

    assert spec.base is not None
    sel = spec.base.selection
    if sel.mode != "mix":
        return []
    param = spec.space.get("selection.eps")
    values = [sel.eps] if param is None else [float(v) for v in param.bounds()]
    where = "selection.eps" if param is None else "the searched selection.eps"
    out = []
    for eps in dict.fromkeys(values):
        config = replace(sel, eps=eps, alpha=sel.alpha or 0.5)
        selection = select(demos.costs, config, demos.scored, demos.safety_dims, demos.episode_ids)
        message = improper_subset_message(selection)
        if message is not None:
            out.append(
                f"{spec.name}: {where} = {eps:g}: {message.split(', so alpha')[0]}; "
                "alpha has no effect there; set an eps in the task's cost units"
            )
    return out


def _config_json(config: Any) -> Any:
    """A (nested) config dataclass as JSON-able values."""
    from dataclasses import asdict

    return json.loads(json.dumps(asdict(config), default=str))


def _param_dict(p: Param) -> dict[str, Any]:
    if isinstance(p, Choice):
        return {"options": list(p.labels())}
    return {f.name: getattr(p, f.name) for f in fields(p)}


def load_study(path: str | Path) -> StudySpec:
    """Import a study file by path and return its ``STUDY``.

    Raises:
        FileNotFoundError: no such file.
        ValueError: the file does not define ``STUDY`` as a ``StudySpec``, or running it
            failed (a syntax error, a failing import, a bad value): one line naming the file,
            the line and the problem.
    """
    module = run_config_file(path, "study file", "tune_jobs/<name>.py", "safe_bc_tune_jobs_")
    study = getattr(module, "STUDY", None)
    if not isinstance(study, StudySpec):
        got = "nothing" if study is None else type(study).__name__
        raise ValueError(
            f"{path}: must define STUDY = StudySpec(...) (from safe_bc.study.spec), found {got}"
        )
    return study


# --- feasibility, trial table, winner ---------------------------------------------------------

CONSTRAINT = "constraint"
"""Column / result key of the larger of the constraints (<= 0 feasible)."""
CONSTRAINTS = {
    "safety": "constraint_safety",
    "violations": "constraint_violation",
    "deferral": "constraint_deferral",
}
"""Optuna constraint name -> result key; each is handed to Optuna (``<= 0`` feasible)."""
CONSTRAINT_NAMES = {
    "constraint_safety": "safety mean below the threshold",
    "constraint_violation": "too many episodes beyond d_s",
    "constraint_deferral": "too many steps deferred",
}
"""What each constraint key says when it is missed (``> 0``)."""


def missed(row: Mapping[str, Any]) -> list[str]:
    """What a trial or candidate (its result or table row) missed: each constraint ``> 0`` (or
    NaN) named, with its value.

    >>> missed({"constraint_safety": 0.2, "constraint_violation": -1.0})
    ['safety mean below the threshold (constraint_safety +0.2)']
    """
    return [
        f"{what} ({key} {float(row[key]):+.3g})"
        for key, what in CONSTRAINT_NAMES.items()
        if key in row and not float(row[key]) <= 0
    ]


OBJECTIVE = "reward_mean"
"""The maximised metric."""

METRICS_BEFORE_STAGES: tuple[str, ...] = (
    "reward_mean",
    "reward_std",
    "reward_lcb",
    "safety_mean",
    "safety_std",
    "safety_min",
    "violation_steps",
    "violation_rate",
    "any_violation",
    "violation_share_ucb",
    "worst_excursion",
    "offroad_steps",
    "critical_share",
    "steps_mean",
    "episodes",
    "train_seeds",
    "threshold",
    "constraint_safety",
    "constraint_violation",
    "constraint_deferral",
    "constraint",
    "feasible",
    "deferred_share",
    "train_loss",
    "train_seconds",
)
"""The trial table's metric columns before the stages' (evaluation, constraints, training)."""
METRICS_AFTER_STAGES: tuple[str, ...] = (
    "eval_seconds",
    "round_eval_seconds",
    "store_seconds",
    "duration_s",
    "train_seed",
    "eval_seed",
    "eval_seeds",
    "n_critical",
    "critical_fraction",
    "resumed",
    "phase",
    "error",
)
"""The trial table's metric columns after the stages' (timings, the training seed)."""


def trial_metrics() -> tuple[str, ...]:
    """What every trial reports (each report carries all keys; NaN where not known yet): the
    trial table's metric columns, the registered stages' report keys among them, read when the
    study runs (a plug-in method registered after import is counted)."""
    return (*METRICS_BEFORE_STAGES, *stage_metrics(), *METRICS_AFTER_STAGES)


def __getattr__(name: str) -> Any:
    if name == "TRIAL_METRICS":  # the name earlier code imports: the live list
        return trial_metrics()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


TRIAL_INFO = ("trial_id", "trial_number", "status", "iterations")
"""Bookkeeping columns in front of the table (``trial_number``: the suggestion order, also the
Optuna trial number; -1 when unknown, e.g. an unbatched study run before it was recorded)."""


@dataclass(frozen=True)
class ConstraintBars:
    """The bars a study's constraints hold a policy to (from the expert's demonstrations):
    the safety-mean threshold and the violation rule. Not the critical zone
    (:class:`safe_bc.selection.CriticalZone`)."""

    threshold: float
    """The safety-mean threshold (the expert's safety mean, or the study's own)."""
    dim_thresholds: Mapping[str, float]
    """Per-dimension safety-mean thresholds (used with ``safety_constraint="per_dim"``)."""
    violation_tolerance: float
    """Largest allowed ``violation_rate``."""
    safety_constraint: SafetyConstraint = "combined"
    """Which safety constraint applies."""
    violation_bound: float | None = None
    """With a confidence: the violation constraint is the Clopper-Pearson upper bound on the
    share of episodes beyond ``d_s`` minus ``violation_share_limit`` (``StudySpec``)."""
    violation_share_limit: float = 0.2
    """Largest allowed upper bound on that share."""
    deferred_share_limit: float = 1.0
    """Largest allowed mean share of steps on which the expert acted (``deferred_share``; a
    policy without a handover defers on none)."""


def constraints(metrics: Mapping[str, float], limits: ConstraintBars) -> dict[str, float]:
    """``constraint_safety``, ``constraint_violation`` and their maximum ``constraint`` for a
    policy's mean metrics (``safety_mean``, ``safety_<dim>_mean``, ``violation_rate``; with
    ``limits.violation_bound`` the share of episodes with a violation ``any_violation`` and
    their count ``episodes`` or ``n_episodes``); each ``<= 0`` when met, NaN when a metric is
    missing.

    >>> lim = ConstraintBars(6.0, {"left": 7.0}, 0.0, "per_dim")
    >>> c = constraints({"safety_mean": 6.5, "safety_left_mean": 6.8, "violation_rate": 0.0}, lim)
    >>> c["constraint_safety"], c["constraint_violation"], c["constraint_deferral"], c["constraint"]
    (0.2..., 0.0, -1.0, 0.2...)
    >>> bound = ConstraintBars(6.0, {}, 0.0, violation_bound=0.95, violation_share_limit=0.2)
    >>> m = {"safety_mean": 7.0, "any_violation": 0.0, "episodes": 20}
    >>> round(constraints(m, bound)["constraint_violation"], 4)  # 13.9% - 20%
    -0.0609
    """
    gaps = [constraint_value(limits.threshold, metrics.get("safety_mean", math.nan))]
    if limits.safety_constraint == "per_dim":
        for dim, thr in limits.dim_thresholds.items():
            gaps.append(constraint_value(thr, metrics.get(f"safety_{dim}_mean", math.nan)))
    safety = math.nan if any(math.isnan(g) for g in gaps) else max(gaps)
    if limits.violation_bound is None:
        violation = float(metrics.get("violation_rate", math.nan)) - limits.violation_tolerance
    else:
        violation = episode_share_bound(metrics, limits.violation_bound)
        violation -= limits.violation_share_limit
    deferred = metrics.get("deferred_share", 0.0)
    deferral = (0.0 if deferred is None or math.isnan(deferred) else float(deferred)) - (
        limits.deferred_share_limit
    )
    both = math.nan if math.isnan(safety) or math.isnan(violation) else max(safety, violation)
    if not math.isnan(both):
        both = max(both, deferral)
    return {
        "constraint_safety": safety,
        "constraint_violation": violation,
        "constraint_deferral": deferral,
        "constraint": both,
    }


def episode_share_bound(metrics: Mapping[str, float], confidence: float) -> float:
    """The Clopper-Pearson upper bound on the share of episodes beyond ``d_s`` from a policy's
    ``any_violation`` (share) and ``episodes`` (or ``n_episodes``) count; NaN when missing.

    >>> round(episode_share_bound({"any_violation": 0.0, "n_episodes": 51}, 0.95), 4)
    0.057
    """
    from safe_bc.metrics import clopper_pearson_upper

    share = float(metrics.get("any_violation", math.nan))
    n = float(metrics.get("episodes", metrics.get("n_episodes", math.nan)))
    if not (math.isfinite(share) and math.isfinite(n) and n >= 1):
        return math.nan
    return clopper_pearson_upper(round(share * n), int(n), confidence)


def constraint_value(threshold: float, safety_mean: float) -> float:
    """``threshold - safety_mean``: ``<= 0`` is feasible (NaN stays NaN).

    >>> constraint_value(5.0, 6.5), constraint_value(5.0, 4.0)
    (-1.5, 1.0)
    """
    return float(threshold) - float(safety_mean)


def is_feasible(constraint: float) -> bool:
    """``constraint <= 0``; NaN is infeasible."""
    return bool(constraint <= 0.0)


def trial_table(records: Sequence[Mapping[str, Any]], params: Sequence[str]) -> pd.DataFrame:
    """One row per trial (in the order given): bookkeeping, every config value, every metric.

    ``records`` hold ``trial_id``, ``trial_number``, ``status``, the parameters and the metrics
    (missing keys become NaN: e.g. a trial that errored before reporting). ``feasible`` is
    recomputed from ``constraint`` so that NaN counts as infeasible.
    """
    cols = [*TRIAL_INFO, *params, *trial_metrics()]
    frame = pd.DataFrame([{c: r.get(c, np.nan) for c in cols} for r in records], columns=cols)
    for c in ("constraint", *CONSTRAINTS.values()):
        frame[c] = pd.to_numeric(frame[c], errors="coerce").astype(float)
    frame["feasible"] = (frame["constraint"] <= 0) & np.isfinite(
        pd.to_numeric(frame["reward_mean"], errors="coerce").astype(float)
    )
    for c in ("error", "phase", "eval_seeds", "status", "trial_id"):
        frame[c] = frame[c].map(lambda v: "" if is_missing(v) else str(v))
    frame["trial_number"] = frame["trial_number"].map(lambda v: -1 if is_missing(v) else int(v))
    return frame


@dataclass(frozen=True)
class Winner:
    """The chosen trial."""

    trial_id: str
    """Tune trial id."""
    feasible: bool
    """False: no trial met the constraint; this is the closest one."""
    row: dict[str, Any]
    """Its row of the trial table."""
    message: str
    """One line saying how it was chosen."""


def choose_winner(trials: pd.DataFrame, objective: str = OBJECTIVE) -> Winner | None:
    """The feasible trial with the highest ``objective`` (the reward, or its lower bound),
    else the least infeasible one.

    Only trials with a finite reward and constraint count (finished evaluations). Ties go to
    the higher safety mean, then the lower trial id. ``None`` when no trial finished.
    """
    done = _finished(trials)
    if done.empty:
        return None
    feasible = done[done["constraint"] <= 0]
    if not feasible.empty:
        best = feasible.sort_values(
            [objective, "safety_mean", "trial_id"], ascending=[False, False, True]
        ).iloc[0]
        msg = (
            f"winner {best['trial_id']}: highest reward {best['reward_mean']:.1f} among "
            f"{len(feasible)}/{len(done)} feasible trials (safety {best['safety_mean']:.2f} "
            f">= threshold {best['threshold']:.2f}, violation constraint met)"
        )
        return Winner(str(best["trial_id"]), True, _row(best), msg)
    best = done.sort_values(
        ["constraint", objective, "trial_id"], ascending=[True, False, True]
    ).iloc[0]
    msg = (
        f"no feasible trial among {len(done)}: closest is {best['trial_id']} (safety mean "
        f"{best['safety_mean']:.2f} vs threshold {best['threshold']:.2f}, violation "
        f"{best['constraint']:.2f}, violation rate {best.get('violation_rate', float('nan')):.3g}"
        f", reward {best['reward_mean']:.1f})"
    )
    return Winner(str(best["trial_id"]), False, _row(best), msg)


def _finished(trials: pd.DataFrame) -> pd.DataFrame:
    """Trials with a finite reward and constraint on their full evaluation (trials that the
    screening stopped are left out when the table says which those are)."""
    ok = np.isfinite(trials["reward_mean"].astype(float)) & np.isfinite(
        trials["constraint"].astype(float)
    )
    if "status" in trials and (trials["status"] == "done").any():
        ok &= trials["status"] == "done"
    return trials[ok]


def choose_candidates(trials: pd.DataFrame, k: int, objective: str = OBJECTIVE) -> pd.DataFrame:
    """The final phase's candidates: up to ``k`` fully evaluated trials, feasible ones first by
    ``objective``, then the least infeasible (smallest ``constraint``)."""
    done = _finished(trials).assign(_f=lambda t: t["constraint"] <= 0)
    feasible = done[done["_f"]].sort_values(
        [objective, "safety_mean", "trial_id"], ascending=[False, False, True]
    )
    rest = done[~done["_f"]].sort_values(
        ["constraint", objective, "trial_id"], ascending=[True, False, True]
    )
    return pd.concat([feasible, rest]).head(k).drop(columns="_f").reset_index(drop=True)


def is_missing(v: Any) -> bool:
    return v is None or (isinstance(v, float) and math.isnan(v))


def _row(s: pd.Series) -> dict[str, Any]:
    return {k: (v.item() if isinstance(v, np.generic) else v) for k, v in s.items()}


def summary_lines(trials: pd.DataFrame, params: Sequence[str], top: int = 10) -> str:
    """The best trials as a short text table: feasible first, then by reward."""
    cols = ["trial_id", "status", "reward_mean", "safety_mean", "violation_rate", "constraint",
            "feasible", *params]  # fmt: skip
    order = trials.assign(_f=trials["feasible"].astype(bool)).sort_values(
        ["_f", "reward_mean"], ascending=[False, False], na_position="last"
    )
    view = order[[c for c in cols if c in order]].head(top).copy()
    view.columns = [c.rsplit(".", 1)[-1] for c in view.columns]
    return view.to_string(index=False, float_format=lambda x: f"{x:.3g}") + CONSTRAINT_KEY


CONSTRAINT_KEY = (
    "\nconstraint: the largest of the constraints, each <= 0 when met: the safety threshold "
    "minus the safety mean; the share of steps beyond d_s (with a violation bound: the upper "
    "confidence bound on the share of episodes beyond d_s) minus its limit; the deferred share "
    "minus its limit"
)
"""The line under the trial table that says what its ``constraint`` column holds."""


# --- what batched suggestions cost in wall-clock -------------------------------------------------


def schedule_seconds(
    durations: Sequence[float], slots: int, batch_size: int | None = None
) -> float:
    """Wall-clock of running trials of these ``durations`` (in suggestion order) on ``slots``
    concurrent slots: each trial starts on the first free slot; with ``batch_size`` a batch's
    trials start only once every trial of the previous batch has finished (the study's
    deterministic batches). Start-up and the sampler's own time are left out.

    >>> schedule_seconds([10, 1, 1, 10], slots=2), schedule_seconds([10, 1, 1, 10], 2, 2)
    (12.0, 20.0)
    """
    if slots < 1:
        raise ValueError(f"slots must be >= 1, got {slots}")
    size = len(durations) if batch_size is None else batch_size
    if size < 1:
        raise ValueError(f"batch_size must be >= 1 or None, got {batch_size}")
    start = 0.0
    for i in range(0, len(durations), size):
        free = [start] * slots
        for d in durations[i : i + size]:
            j = int(np.argmin(free))
            free[j] += float(d)
        start = max(free)
    return start
