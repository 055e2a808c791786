"""The method registry: ``METHODS``, name -> :class:`MethodSpec`, filled by
:func:`register_method`.

A *method* here is an improver: from a start agent (a trained behaviour-cloning net with its
selection and BC settings), its demonstrations and its task's env to an improved agent, in a
folder of its own, resumable (a rerun of the same start and config picks up where it stopped;
another start or config there is an error or is redone). Its settings are one frozen config
record (a dataclass with a ``seed`` field and ``to_dict``) that is also its identity.

One entry serves every place that runs methods:

* the study: every registered method is a stage (:mod:`safe_bc.methods.stages`), on when the
  study sets its config (:meth:`safe_bc.study.spec.StudySpec.stage_base`), searchable as
  ``<name>.<field>`` keys (:attr:`MethodSpec.prefix`);
* the comparison runner: a row ``FromStart(name, start=..., config=...)`` of
  :mod:`safe_bc.compare.spec` improves every training seed's agent of its start row;
* the command line: ``safe-bc method NAME --start CKPT --out DIR --config.<field> ...``; the
  commands from before it (``safe-bc query``, ``safe-bc improve``) are entries of
  :data:`METHOD_COMMANDS` (:class:`MethodCommand`: their records and runners live beside their
  methods' code).

Adding a method is one module holding its runner (``run(config, start, folder, *,
metadata=None) -> Improved``), one :func:`register_method` line and its tests; a method
defined outside the package registers itself the same way (``tests/test_method_plugin.py``).
This module is pure: runners are imported only when they run.
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from safe_bc.run_config import RunConfig

SHARED = "_shared"
"""The folder, in a runs folder, of results its runs share (a method's folder name never starts
with ``_``: :func:`safe_bc.compare.spec.run_slug` strips it)."""


@dataclass(frozen=True)
class Start:
    """What an improver starts from."""

    agent: Any
    """The trained net (:class:`safe_bc.bc.BCNet`)."""
    run_config: RunConfig
    """Its selection and BC settings (the training seed included)."""
    demos: str | Path
    """The demonstration set it was trained on (its limits ``d_s`` are the run's)."""
    env: Any
    """The env it runs in (a :class:`safe_bc.tasks.env_config.EnvConfig`)."""
    checkpoint: Path | None = None
    """Its ``safe-bc train`` checkpoint, where it is one (a comparison's ``agent/``, the
    command line's ``--start``); ``None``: only in memory (a study trial's net)."""
    data: Any = None
    """``demos`` loaded (:class:`safe_bc.data.store.Demonstrations`); ``None``: the runner
    loads them."""
    parallel: Any = None
    """How a run with ``workers`` > 0 spreads its rollouts (:data:`safe_bc.methods.rounds.Parallel`,
    e.g. the distributed layer's Ray actors); ``None``: a run asking for workers is refused."""
    on_round: Any = None
    """Called with each finished round's or iteration's summary (a progress bar); ``None``:
    nothing."""
    shared: Path | None = None
    """Where runs from this start store and read work they would repeat identically (a
    comparison's ``<runs folder>/``:data:`SHARED`: e.g. the self-imitation runs' start
    validation and expert runs, content-keyed); ``None``: nothing shared."""


@dataclass(frozen=True)
class Improved:
    """What an improver returns."""

    policy: Any
    """The improved agent as it is evaluated (a policy source of :mod:`safe_bc.rollout.evaluate`,
    e.g. behind its own shield)."""
    net: Any
    """The improved agent alone (a policy source without any shield): what a handover row of
    a comparison wraps."""
    report: dict[str, float]
    """The method's report values (:attr:`MethodSpec.metrics`, columns of a study's trials)."""
    history: Any = None
    """The run's learning curve (a ``pandas.DataFrame``: a row per iteration or round with
    ``seconds`` and ``env_steps``), or ``None``."""
    meta: dict[str, Any] | None = None
    """Provenance of the run as stored with it (the machine that ran it); ``None``: the
    runner stores none (the comparison runner records the machine in ``run.json``)."""
    fresh: bool = True
    """Whether this call did work (``False``: everything was on disk already)."""
    result: Any = None
    """The method's own result record."""


Runner = Callable[..., Improved]
"""``run(config, start, folder, *, metadata=None) -> Improved``."""

EnvGroups = Callable[[int], Any]
"""``envs(workers)``: a factory of env groups stepped by ``workers`` Ray actors (an
``EnvGroupFactory`` of :mod:`safe_bc.methods.improve.envs`), the distributed layer's, handed to
a :class:`MethodCommand` by the command line."""


@dataclass(frozen=True)
class MethodSpec:
    """One method (see the module docstring)."""

    name: str
    """The key in :data:`METHODS`: the study stage's name and search prefix
    (``"<name>."``), the key of its config in a comparison cell's identity and the
    ``mode`` of its comparison rows."""
    config: type
    """Its config record's type (a frozen dataclass with ``seed`` and ``to_dict``)."""
    runner: str
    """``"module:function"`` of its runner (:data:`Runner`)."""
    metrics: tuple[str, ...] = ()
    """The keys of :attr:`Improved.report` (trial table columns)."""
    summed: tuple[str, ...] = ()
    """Of :attr:`metrics`, those summed over a trial's training seeds (the rest: the first
    seed's)."""
    label: str = ""
    """What progress lines call a run (``"improving"``)."""
    folder: str = ""
    """A comparison cell's subfolder of the run (``""``: :attr:`name`)."""
    identity: str = ""
    """``"module:function"`` ``(config, task) -> dict``: what makes a run of this config on
    ``task`` (the cell identity of comparison rows); ``""``: ``config.to_dict()``."""
    start_modes: tuple[str, ...] = ()
    """Selection modes a start row may have (``()``: any)."""
    shares_rounds: bool = False
    """A run is a sequence of rounds that depend only on the settings and the rounds before
    them: a comparison seeds a new run with the done rounds of a shorter run of the same
    settings (its config has ``rounds``; its folder ``round_<r>/done.json``)."""
    flat_field: bool = False
    """A comparison's flat record (:meth:`safe_bc.compare.rows.Row.record`) has a field of its
    own named after it, holding its rows' config, and the flat spelling takes it
    (``Method(row, <name>=config, start=...)``): the methods comparisons were first written
    with. A method without one records its rows as ``method`` and ``config``; setting it on a
    method added since would add a field to every comparison's recorded configuration."""

    def __post_init__(self) -> None:
        if not self.name.isidentifier():
            raise ValueError(f"a method's name is an identifier, got {self.name!r}")
        if not dataclasses.is_dataclass(self.config):
            raise ValueError(f"method {self.name!r}: config must be a dataclass type")
        if "seed" not in {f.name for f in dataclasses.fields(self.config)}:
            raise ValueError(f"method {self.name!r}: its config needs a seed field")
        if ":" not in self.runner:
            raise ValueError(f"method {self.name!r}: runner is 'module:function'")
        if not set(self.summed) <= set(self.metrics):
            raise ValueError(f"method {self.name!r}: summed {self.summed} not among metrics")

    @property
    def subfolder(self) -> str:
        """The run's subfolder of a comparison cell."""
        return self.folder or self.name

    @property
    def prefix(self) -> str:
        """A study's search keys of this method start with it (``"improve."``)."""
        return f"{self.name}."

    def reduce(self, per_seed: Sequence[Mapping[str, float]]) -> dict[str, float]:
        """One report from every training seed's report values: :attr:`summed` keys added up,
        the others the first seed's.

        >>> METHODS["improve"].reduce([{"improve_seconds": 2.0, "improve_kept_iteration": 5},
        ...                            {"improve_seconds": 3.0, "improve_kept_iteration": 7}])
        {'improve_seconds': 5.0, 'improve_kept_iteration': 5}
        """
        out = dict(per_seed[0])
        for key in self.summed:
            out[key] = sum(v[key] for v in per_seed)
        return out

    def load(self) -> Runner:
        """The runner function (imports its module)."""
        return _load(self.runner)

    def run(self, config: Any, start: Start, folder: str | Path, **kwargs: Any) -> Improved:
        """Run (or resume) ``config`` from ``start`` in ``folder``."""
        self.check(config)
        return self.load()(config, start, Path(folder), **kwargs)

    def check(self, config: Any) -> None:
        """Refuse a config of another type (one line naming the method)."""
        if not isinstance(config, self.config):
            raise ValueError(
                f"method {self.name!r} takes a config of type {self.config.__name__}, "
                f"got {type(config).__name__}"
            )

    def identify(self, config: Any, task: str) -> Any:
        """What makes a run of ``config`` on ``task`` (:attr:`identity`)."""
        if self.identity:
            return _load(self.identity)(config, task)
        return config.to_dict()


def _load(target: str) -> Callable[..., Any]:
    module, _, name = target.partition(":")
    return getattr(importlib.import_module(module), name)


@dataclass(frozen=True)
class MethodCommand:
    """A command of its own that runs a method, from before ``safe-bc method NAME``: it runs as
    it did (its own flags, its own summary), then one line to stderr names its ``safe-bc method
    NAME`` form."""

    name: str
    """The command: ``safe-bc <name>``."""
    job: str
    """``"module:Class"`` of its record (a frozen dataclass: its fields are the flags)."""
    runner: str
    """``"module:function"``: ``run(job, *, parallel, envs) -> (summary, result)``, given the
    distributed layer's :attr:`Start.parallel` and :data:`EnvGroups` by the command line."""
    configs: tuple[tuple[str | None, str], ...] = ((None, "config"),)
    """Its ``--method`` values (``None``: it has no such flag; the first: the default), each with
    the field of its record holding the config it runs: the method of its ``safe-bc method``
    form is the registered one taking that config."""

    def __post_init__(self) -> None:
        if ":" not in self.job or ":" not in self.runner:
            raise ValueError(f"command {self.name!r}: job and runner are 'module:name'")
        if not self.configs:
            raise ValueError(f"command {self.name!r}: configs names at least one field")

    @property
    def record_name(self) -> str:
        """The name of its record's class (``"QueryJob"``)."""
        return self.job.rpartition(":")[2]

    def record(self) -> type:
        """Its record's class (imports its module)."""
        return _load(self.job)  # type: ignore[return-value]

    def load(self) -> Callable[..., tuple[str, Any]]:
        """Its runner (imports its module)."""
        return _load(self.runner)


METHOD_COMMANDS: dict[str, MethodCommand] = {}
"""Command name -> the :class:`MethodCommand` from before ``safe-bc method NAME``, in the order
the command line lists them. Add with :func:`register_command`."""


def register_command(command: MethodCommand) -> MethodCommand:
    """Add ``command`` to :data:`METHOD_COMMANDS` (the same again does nothing; another under a
    taken name is an error)."""
    return _register(METHOD_COMMANDS, command, "command")


METHODS: dict[str, MethodSpec] = {}
"""Method name -> its spec, in registration order (the order study stages run in). Add with
:func:`register_method`; ``tests/test_methods.py`` walks every entry."""


def register_method(spec: MethodSpec) -> MethodSpec:
    """Add ``spec`` to :data:`METHODS`. Registering the same spec again does nothing; another
    spec under a taken name is an error."""
    return _register(METHODS, spec, "method")


def _register(table: dict[str, Any], entry: Any, kind: str) -> Any:
    """``entry`` added to ``table`` under its ``name``; the same again does nothing, another
    under a taken name is an error."""
    known = table.get(entry.name)
    if known is not None:
        if known != entry:
            raise ValueError(f"{kind} {entry.name!r} is registered already")
        return known
    table[entry.name] = entry
    return entry


def method_of(name: str) -> MethodSpec:
    """The registered method ``name`` (one line naming the known ones otherwise)."""
    if name not in METHODS:
        raise ValueError(f"unknown method {name!r}: choose {', '.join(METHODS)}")
    return METHODS[name]


def method_of_config(config: Any) -> MethodSpec:
    """The registered method whose config type ``config`` is."""
    for spec in METHODS.values():
        if type(config) is spec.config:
            return spec
    raise ValueError(f"no registered method takes a config of type {type(config).__name__}")
