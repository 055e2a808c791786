"""The rows of a comparison: a small closed set of kinds, one frozen record each.

* :class:`Agent`: a behaviour-cloning agent per training seed (a selection rule and,
  optionally, its own network, budget, demonstrations and renderer);
* :class:`Expert`: the task's expert (evaluated once), optionally with its own settings;
* :class:`FromStart`: a registered method (:data:`safe_bc.methods.METHODS`) run from each
  training seed's agent of an :class:`Agent` row;
* :class:`Handover`: the agents of another row with the scripted expert acting in their
  critical states (the comparison's zone, or a :class:`~safe_bc.handover.HandoverConfig`);
* :class:`View`: the agents of an :class:`Agent` row evaluated another way (another renderer,
  or CarRacing's steering indicator masked).

Every kind meets one interface, :class:`Row`: its training seeds and cell folders, the
demonstrations behind it, the BC agent it trains (if any), what its cell needs trained first,
the ``run`` part of its cells' stamps (:meth:`Row.run_stamp`, what names a stored evaluation)
and the policy its cell evaluates (:meth:`Row.policy`, made through the runner's
:class:`Runs`). The runner (:mod:`safe_bc.compare.run`) calls that interface and never asks a
row's kind. The rows are pure: a comparison is handed in (anything with the
:class:`~safe_bc.compare.spec.Comparison` attributes they read), and the effects (loading an
agent, running a method) are the runner's.

A comparison's recorded configuration lists each row as the flat record comparisons were
first written with (:meth:`Row.record`, fields :data:`FLAT_FIELDS`), so recorded
configurations stay what they were; :func:`Method` builds a row from that flat spelling. The
methods with a field of their own in it are read from the registry
(:attr:`safe_bc.methods.MethodSpec.flat_field`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from safe_bc.bc.config import BCConfig
from safe_bc.handover import HandoverConfig
from safe_bc.methods import METHODS, method_of, method_of_config
from safe_bc.run_config import RunConfig
from safe_bc.selection import SelectionConfig
from safe_bc.tasks.env_config import Renderer, canonical_renderer

EXPERT = "expert"
"""``mode`` (and default name) of the expert's row; the default expert's policy key."""

FLAT_METHODS = tuple(name for name, spec in METHODS.items() if spec.flat_field)
"""Methods the flat record has a field of its own for, in registration order
(:attr:`safe_bc.methods.MethodSpec.flat_field`; other methods: ``method``, ``config``)."""

FLAT_FIELDS: dict[str, Any] = {
    "name": "",
    "selection": None,
    "bc": None,
    "expert": False,
    "expert_config": None,
    **dict.fromkeys(FLAT_METHODS),
    "start": "",
    "fallback_of": "",
    "defer_width": None,
    "defer_hold": 0,
    "defer_lookahead": 0,
    "defer_hold_on": (),
    "seeds": (),
    "masked_of": "",
    "label": "",
    "agents_of": "",
    "renderer": None,
    "demos": None,
}
"""The flat record's fields, in its order, with their values on a row that does not set them
(a method's field: ``None``)."""


def _renderer(name: str, renderer: Renderer | None) -> Renderer | None:
    if renderer is None:
        return None
    try:
        return canonical_renderer(renderer)
    except ValueError as e:
        raise ValueError(f"method {name!r}: {e}") from None


def _plain(value: Any) -> Any:
    return dataclasses.asdict(value) if dataclasses.is_dataclass(value) else value


class Runs(Protocol):
    """What the runner gives a row to make its policy and its run: the effects (files, Ray)
    stay in the runner, which of them a row needs is the row's."""

    comparison: Any
    """The comparison being run."""

    def agent(self, row: Agent, seed: int) -> Any:
        """The trained BC agent of ``row`` for ``seed``, as a policy source."""
        ...

    def improved(self, row: FromStart, seed: int) -> Any:
        """The finished run of ``row`` for ``seed`` (:class:`~safe_bc.methods.Improved`)."""
        ...

    def run_method(self, row: FromStart, seed: int) -> Any:
        """Run (or resume) ``row``'s method for ``seed``: its :class:`~safe_bc.methods.Improved`."""
        ...

    def expert(self, config: Any) -> Any:
        """The task's expert with ``config`` (``None``: the demonstrations' own)."""
        ...

    def masked(self, source: Any) -> Any:
        """``source`` with the steering indicator painted black."""
        ...

    def handover(self, row: Handover, net: Any, seed: int) -> Any:
        """``net`` with the scripted expert acting where ``row`` hands over."""
        ...


@dataclass(frozen=True)
class Row:
    """The interface every kind of row meets (the module doc); ``c`` is the comparison."""

    @property
    def shown(self) -> str:
        """``label``, or ``name``."""
        return self.label or self.name  # type: ignore[attr-defined]

    @property
    def source(self) -> str:
        """The row whose agents this row uses (``""``: its own)."""
        return ""

    @property
    def labels(self) -> dict[str, Any]:
        """Columns that identify the row in the episodes table."""
        return {"method": self.name, "mode": self.kind, "alpha": float("nan"), "rest": ""}  # type: ignore[attr-defined]

    def policy_key(self, seed: int) -> str:
        """Its cell's policy in the episode tables."""
        return f"{self.name} seed={seed}"  # type: ignore[attr-defined]

    def seeds_in(self, c: Any) -> tuple[int, ...]:
        """Its training seeds (a derived row: its source row's)."""
        return c.seeds_of(c.method(self.source))

    def cell_folder(self, base: Path, seed: int) -> Path:
        """Its cell's folder for ``seed`` under its own runs folder ``base``."""
        return base / f"seed{seed}"

    def demos_in(self, c: Any) -> Path:
        """The demonstrations behind its agents (those of the row it derives from, else the
        comparison's): its evaluation thresholds are their limits."""
        return c.method(self.source).demos_in(c) if self.source else c.demos

    def own_set(self) -> Path | None:
        """A demonstration set of its own, collected if absent (``None``: none)."""
        return None

    def agent_run(self, c: Any, seed: int) -> RunConfig | None:
        """The training run of its own BC agent for ``seed`` (``None``: it trains none)."""
        return None

    def needs(self, c: Any, seed: int) -> tuple[tuple[Row, int], ...]:
        """The cells whose BC agents its cell ``seed`` needs trained first."""
        return ()

    @property
    def budget_of(self) -> str:
        """The row whose run fixes its run's budget (``""``: none)."""
        return ""

    def with_workers(self, workers: int) -> Row:
        """This row with its run's rollout actors set to ``workers``, where it has them."""
        return self

    def curve_refs(self) -> tuple[str, ...]:
        """The rows whose held-out reward the learning-curve figure draws beside it."""
        return ()

    def run_stamp(self, c: Any, seed: int) -> dict[str, Any]:
        """What makes its cell ``seed``'s policy: the stamp's ``run``
        (:func:`safe_bc.compare.run.cell_stamp`)."""
        raise NotImplementedError

    def method_run(self, runs: Runs, seed: int) -> Any:
        """Run (or resume) its method for ``seed`` (``None``: it runs none)."""
        return None

    def policy(self, runs: Runs, seed: int) -> Any:
        """The policy its cell ``seed`` evaluates."""
        raise NotImplementedError

    def net(self, runs: Runs, seed: int) -> Any:
        """The net that a handover over this row hands over from."""
        raise ValueError(f"row {self.name!r} has no agents to hand over")  # type: ignore[attr-defined]

    def spelling(self) -> dict[str, Any]:
        """This row's values of :data:`FLAT_FIELDS` that differ from the defaults (for a
        method without a flat field, ``method`` and ``config``): ``Method(**spelling)``
        builds it back."""
        raise NotImplementedError

    def record(self) -> dict[str, Any]:
        """The flat record as ``dataclasses.asdict`` wrote it: every field of
        :data:`FLAT_FIELDS` in order, configs as dicts (then, for a method without a flat
        field, ``method`` and ``config``)."""
        own = self.spelling()
        out = {k: _plain(own.get(k, v)) for k, v in FLAT_FIELDS.items()}
        for k in ("method", "config"):
            if k in own:
                out[k] = _plain(own[k])
        return out


@dataclass(frozen=True)
class Agent(Row):
    """A behaviour-cloning agent per training seed."""

    name: str
    """Row label (unique in the comparison), e.g. ``alpha=0.5 (rest=all)``."""
    selection: SelectionConfig
    """``T_eps`` and the training rule of its agents (``eps`` unset: the comparison's width,
    :attr:`safe_bc.compare.spec.Comparison.eps`, else the task's)."""
    bc: BCConfig | None = None
    """Its network, preprocessing and budget; ``None``: the comparison's ``bc``."""
    seeds: tuple[int, ...] = ()
    """Its training seeds, a subset of the comparison's (``()``: all of them)."""
    label: str = ""
    """How the Markdown names the row (``""``: ``name``); ``name`` stays the table's key and
    seeds the row's bootstrap draws (:func:`safe_bc.metrics.keyed_rng`)."""
    renderer: Renderer | None = None
    """How its evaluation env draws (``None``: the default, ``raster``); with its own
    ``demos`` it also collects them with it. Ignored by tasks without renderers."""
    demos: Path | None = None
    """Its own demonstration set (``None``: the comparison's), built with the task's default
    collection drawn by ``renderer`` if absent; its limits d_s are the row's (and its views')
    evaluation thresholds."""

    kind = "bc"

    def __post_init__(self) -> None:
        if not self.name:
            raise ValueError("a method needs a name")
        if not isinstance(self.selection, SelectionConfig):
            raise ValueError(f"method {self.name!r}: selection must be a SelectionConfig")
        object.__setattr__(self, "renderer", _renderer(self.name, self.renderer))

    def seeds_in(self, c: Any) -> tuple[int, ...]:
        return self.seeds or c.train_seeds

    def demos_in(self, c: Any) -> Path:
        return self.demos or c.demos

    def own_set(self) -> Path | None:
        return self.demos

    def agent_run(self, c: Any, seed: int) -> RunConfig:
        """Its agent's run for ``seed``: its selection, its ``bc`` (else the comparison's)
        with the training seed set."""
        bc = self.bc or c.bc
        return RunConfig(
            self.selection, dataclasses.replace(bc, train=dataclasses.replace(bc.train, seed=seed))
        )

    def needs(self, c: Any, seed: int) -> tuple[tuple[Row, int], ...]:
        return ((self, seed),)

    def run_stamp(self, c: Any, seed: int) -> dict[str, Any]:
        run = self.agent_run(c, seed).to_dict()
        if self.demos is not None:  # (rows on the comparison's demos keep their stamps)
            run = {**run, "demos": str(self.demos)}
        return run

    def policy(self, runs: Runs, seed: int) -> Any:
        return runs.agent(self, seed)

    def net(self, runs: Runs, seed: int) -> Any:
        return runs.agent(self, seed)

    def spelling(self) -> dict[str, Any]:
        return {"name": self.name, "selection": self.selection, "bc": self.bc,
                "seeds": self.seeds, "label": self.label, "renderer": self.renderer,
                "demos": self.demos}  # fmt: skip

    @property
    def labels(self) -> dict[str, Any]:
        mix = self.selection.mode == "mix"
        return {
            "method": self.name,
            "mode": self.selection.mode,
            "alpha": self.selection.alpha if mix else float("nan"),
            "rest": self.selection.rest if mix else "",
        }


@dataclass(frozen=True)
class Expert(Row):
    """The task's expert: evaluated once (``train_seed`` 0)."""

    name: str = "expert"
    """Row label (unique in the comparison)."""
    config: Any = None
    """Its own configuration (the task's expert config type); ``None``: the one recorded in
    the comparison's demonstrations. Rows of several settings compare them on one set of
    tracks."""
    label: str = ""
    """How the Markdown names the row (``""``: ``name``)."""
    renderer: Renderer | None = None
    """How its evaluation env draws (``None``: the default)."""

    kind = "expert"

    def __post_init__(self) -> None:
        if not self.name:
            raise ValueError("a method needs a name")
        if self.config is not None and not dataclasses.is_dataclass(self.config):
            raise ValueError(
                f"method {self.name!r}: expert_config must be an expert config (a dataclass), "
                f"got {type(self.config).__name__}"
            )
        object.__setattr__(self, "renderer", _renderer(self.name, self.renderer))

    def policy_key(self, seed: int) -> str:
        """``"expert"`` for the default expert (its stored evaluations' name), else by row."""
        return EXPERT if self.config is None else super().policy_key(seed)

    def seeds_in(self, c: Any) -> tuple[int, ...]:
        return (0,)

    def cell_folder(self, base: Path, seed: int) -> Path:
        return base

    def curve_refs(self) -> tuple[str, ...]:
        return (self.name,)

    def run_stamp(self, c: Any, seed: int) -> dict[str, Any]:
        run: dict[str, Any] = {"expert": str(c.demos)}  # (the default expert's stamp as
        if self.config is not None:  # before its own settings existed)
            run["expert_config"] = dataclasses.asdict(self.config)
        return run

    def policy(self, runs: Runs, seed: int) -> Any:
        return runs.expert(self.config)

    def spelling(self) -> dict[str, Any]:
        return {"name": self.name, "expert": True, "expert_config": self.config,
                "label": self.label, "renderer": self.renderer}  # fmt: skip


@dataclass(frozen=True)
class FromStart(Row):
    """A registered method run from each training seed's agent of an :class:`Agent` row (its
    config's ``seed`` set to the training seed)."""

    name: str
    """Row label (unique in the comparison)."""
    start: str
    """The :class:`Agent` row whose agents it starts from."""
    config: Any
    """The method's config record (:attr:`safe_bc.methods.MethodSpec.config`)."""
    method: str = ""
    """The registered method (``""``: the one whose config type :attr:`config` is)."""
    label: str = ""
    """How the Markdown names the row (``""``: ``name``)."""
    renderer: Renderer | None = None
    """How its evaluation env draws (``None``: the default)."""

    def __post_init__(self) -> None:
        if not self.name:
            raise ValueError("a method needs a name")
        if not self.start:
            raise ValueError(f"method {self.name!r}: start= names the row it improves")
        spec = method_of(self.method) if self.method else method_of_config(self.config)
        try:
            spec.check(self.config)
        except ValueError as e:
            raise ValueError(f"method {self.name!r}: {e}") from None
        object.__setattr__(self, "method", spec.name)
        object.__setattr__(self, "renderer", _renderer(self.name, self.renderer))

    @property
    def kind(self) -> str:  # type: ignore[override]
        """The method's name."""
        return self.method

    @property
    def spec(self) -> Any:
        """The registered method (:class:`safe_bc.methods.MethodSpec`)."""
        return METHODS[self.method]

    @property
    def source(self) -> str:
        return self.start

    def needs(self, c: Any, seed: int) -> tuple[tuple[Row, int], ...]:
        return ((c.method(self.start), seed),)

    @property
    def budget_of(self) -> str:
        """The config's ``budget_of`` (``QueryConfig``: the row whose queries cap its rounds)."""
        return getattr(self.config, "budget_of", "")

    def with_workers(self, workers: int) -> Row:
        if "workers" not in {f.name for f in dataclasses.fields(self.config)}:
            return self
        return dataclasses.replace(self, config=dataclasses.replace(self.config, workers=workers))

    def curve_refs(self) -> tuple[str, ...]:
        return (self.start,)

    def siblings(self, c: Any) -> list[FromStart]:
        """The other rows of ``c`` of the same method from the same start."""
        return [
            x
            for x in c.methods
            if isinstance(x, FromStart)
            and (x.method, x.start) == (self.method, self.start)
            and x.name != self.name
        ]

    def config_for(self, c: Any, seed: int, improved: dict | None = None) -> Any:
        """Its run config for training seed ``seed`` (its ``seed`` set); a config whose
        ``budget_of`` names another row resolved from that row's run of the seed in
        ``improved`` (its :class:`~safe_bc.methods.Improved`, whose report has
        ``queries_total``)."""
        config = dataclasses.replace(self.config, seed=seed)
        if self.budget_of and improved is not None:
            config = config.with_budget(int(improved[self.budget_of, seed].report["queries_total"]))
        return config

    def identity(self, c: Any, seed: int) -> Any:
        """What makes its run for ``seed`` (the method's identity of its config on the
        comparison's task, :meth:`safe_bc.methods.MethodSpec.identify`); a ``budget_of`` row's
        name is replaced by the identity of that row's run, which fixes the budget."""
        identity = self.spec.identify(self.config_for(c, seed), c.task)
        of = identity.get("budget_of", "") if isinstance(identity, dict) else ""
        if of:
            identity = {**identity, "budget_of": c.method(of).identity(c, seed)}
        return identity

    def run_stamp(self, c: Any, seed: int) -> dict[str, Any]:
        start = c.method(self.start).agent_run(c, seed).to_dict()
        return {"start": start, self.method: self.identity(c, seed)}

    def method_run(self, runs: Runs, seed: int) -> Any:
        return runs.run_method(self, seed)

    def policy(self, runs: Runs, seed: int) -> Any:
        return runs.improved(self, seed).policy

    def net(self, runs: Runs, seed: int) -> Any:
        return runs.improved(self, seed).net

    def spelling(self) -> dict[str, Any]:
        own = {"name": self.name, "start": self.start, "label": self.label,
               "renderer": self.renderer}  # fmt: skip
        if self.method in FLAT_METHODS:
            return {**own, self.method: self.config}
        return {**own, "method": self.method, "config": self.config}


@dataclass(frozen=True)
class Handover(Row):
    """The agents of another row (an :class:`Agent` or :class:`FromStart` row; no training of
    their own) with the scripted expert acting in their critical states. The expert is
    privileged (it reads the track): this bounds what a safe fallback would give."""

    name: str
    """Row label (unique in the comparison)."""
    of: str
    """The row whose agents act outside the zone."""
    handover: HandoverConfig | None = None
    """Where the expert acts: the env's measured cost within ``width`` of d_s
    (:class:`safe_bc.rollout.handover.DeferralSource`; the episodes record the share of steps
    deferred); ``None``: the shield's zone (the comparison's eps, costs read off the
    observation)."""
    label: str = ""
    """How the Markdown names the row (``""``: ``name``)."""
    renderer: Renderer | None = None
    """How its evaluation env draws (``None``: the default)."""

    kind = "fallback"

    def __post_init__(self) -> None:
        if not self.name:
            raise ValueError("a method needs a name")
        if self.handover is not None and not isinstance(self.handover, HandoverConfig):
            raise ValueError(f"method {self.name!r}: handover must be a HandoverConfig")
        object.__setattr__(self, "renderer", _renderer(self.name, self.renderer))

    @property
    def source(self) -> str:
        return self.of

    def run_stamp(self, c: Any, seed: int) -> dict[str, Any]:
        of = c.method(self.of).run_stamp(c, seed)
        h = self.handover
        if h is None:
            return {"fallback_of": of, "fallback": "expert", "eps": c.width}
        run: dict[str, Any] = {"fallback_of": of, "deferral": "expert", "width": h.width}
        if h.hold:  # (rows without a hold keep their stamps)
            run["hold"] = h.hold
        if h.lookahead:
            run["lookahead"] = h.lookahead
        if h.hold_on:
            run["hold_on"] = list(h.hold_on)
        if h.widths:
            run["widths"] = dict(h.widths)
        if h.fallback != "expert":
            run["fallback"] = h.fallback
        if h.stall:
            run.update(stall=h.stall, stall_hold=h.stall_hold)
        if h.pace:
            run.update(pace=h.pace, pace_steps=h.pace_steps, pace_hold=h.pace_hold)
        return run

    def policy(self, runs: Runs, seed: int) -> Any:
        return runs.handover(self, runs.comparison.method(self.of).net(runs, seed), seed)

    def spelling(self) -> dict[str, Any]:
        own = {"name": self.name, "fallback_of": self.of, "label": self.label,
               "renderer": self.renderer}  # fmt: skip
        h = self.handover
        if h is not None:
            own.update(defer_width=h.width, defer_hold=h.hold, defer_lookahead=h.lookahead,
                       defer_hold_on=h.hold_on)  # fmt: skip
        return own

    def record(self) -> dict[str, Any]:
        """The flat record, and ``handover`` where the flat fields cannot spell its settings
        (per-dimension widths, a fallback other than the expert, a stall or pace cap)."""
        out = super().record()
        h = self.handover
        if h is not None and (h.widths or h.fallback != "expert" or h.stall or h.pace):
            out["handover"] = h.to_dict()
        return out


@dataclass(frozen=True)
class View(Row):
    """The agents of an :class:`Agent` row (no training of their own) evaluated as they are
    in another env (``renderer``: agents trained on exact frames driving on approximate
    ones), or with CarRacing's steering indicator painted black (``masked``: the copycat
    check, :class:`safe_bc.rollout.evaluate.MaskedSteering`)."""

    name: str
    """Row label (unique in the comparison)."""
    of: str
    """The :class:`Agent` row whose agents it evaluates."""
    masked: bool = False
    """Paint the steering indicator black."""
    renderer: Renderer | None = None
    """How its evaluation env draws (``None``: the default)."""
    label: str = ""
    """How the Markdown names the row (``""``: ``name``)."""

    def __post_init__(self) -> None:
        if not self.name:
            raise ValueError("a method needs a name")
        object.__setattr__(self, "renderer", _renderer(self.name, self.renderer))

    @property
    def kind(self) -> str:  # type: ignore[override]
        """``masked`` or ``view``."""
        return "masked" if self.masked else "view"

    @property
    def source(self) -> str:
        return self.of

    def run_stamp(self, c: Any, seed: int) -> dict[str, Any]:
        of = c.method(self.of).run_stamp(c, seed)
        if self.masked:
            return {"masked_of": of, "view": "steering indicator masked"}
        return {"agents_of": of, "view": "as trained"}

    def policy(self, runs: Runs, seed: int) -> Any:
        agent = runs.comparison.method(self.of).net(runs, seed)
        return runs.masked(agent) if self.masked else agent

    def spelling(self) -> dict[str, Any]:
        key = "masked_of" if self.masked else "agents_of"
        return {"name": self.name, key: self.of, "label": self.label, "renderer": self.renderer}


KINDS = (Agent, Expert, FromStart, Handover, View)
"""Every kind of row."""


def _flat_configs(name: str, configs: dict[str, Any], start: str) -> dict[str, Any]:
    """The methods' configs that a flat spelling gives (its keywords beyond the fixed fields,
    ``None`` ones left out); a keyword that is no method of :data:`FLAT_METHODS` is refused."""
    for key in configs:
        if key not in FLAT_METHODS:
            hint = (
                f" (a {key} row: FromStart({name!r}, start={start!r}, config=...))"
                if key in METHODS
                else ""
            )
            raise TypeError(f"Method() got an unexpected keyword argument {key!r}{hint}")
    return {k: v for k, v in configs.items() if v is not None}


def Method(
    name: str,
    selection: SelectionConfig | None = None,
    bc: BCConfig | None = None,
    expert: bool = False,
    expert_config: Any = None,
    *,
    start: str = "",
    fallback_of: str = "",
    defer_width: float | None = None,
    defer_hold: int = 0,
    defer_lookahead: int = 0,
    defer_hold_on: tuple[str, ...] = (),
    seeds: tuple[int, ...] = (),
    masked_of: str = "",
    label: str = "",
    agents_of: str = "",
    renderer: Renderer | None = None,
    demos: Path | None = None,
    **configs: Any,
) -> Row:
    """The row that the flat spelling describes (its fields: :data:`FLAT_FIELDS`, a method's
    config under the method's name, :data:`FLAT_METHODS`; exactly one of ``selection``,
    ``expert=True``, a method's config, ``fallback_of``, ``masked_of``, ``agents_of``),
    checked as it always was."""
    given = _flat_configs(name, configs, start)
    kinds = [selection is not None, expert, *(m in given for m in FLAT_METHODS),
             bool(fallback_of), bool(masked_of), bool(agents_of)]  # fmt: skip
    if sum(kinds) != 1:
        raise ValueError(
            f"method {name!r}: give exactly one of selection, expert=True, "
            f"{', '.join(FLAT_METHODS)}, fallback_of, masked_of, agents_of"
        )
    if not name:
        raise ValueError("a method needs a name")
    if bool(given) != bool(start):
        fields = " or ".join(f"{m}=" for m in FLAT_METHODS)
        raise ValueError(f"method {name!r}: start= goes with {fields} (and only with them)")
    for method, config in given.items():
        kind = METHODS[method].config
        if not isinstance(config, kind):
            article = "an" if kind.__name__[:1] in "AEIOU" else "a"
            raise ValueError(
                f"method {name!r}: {method} must be {article} {kind.__name__}, got "
                f"{type(config).__name__}"
            )
    if bc is not None and selection is None:
        raise ValueError(f"method {name!r}: bc= is for BC rows (with selection=)")
    renderer = _renderer(name, renderer)
    if demos is not None and selection is None:
        raise ValueError(f"method {name!r}: demos= is for BC rows (with selection=)")
    if defer_width is not None and not (
        fallback_of and math.isfinite(defer_width) and defer_width >= 0
    ):
        raise ValueError(
            f"method {name!r}: defer_width= is a finite width >= 0 for fallback rows "
            f"(with fallback_of=), got {defer_width}"
        )
    for field, steps in (("defer_hold", defer_hold), ("defer_lookahead", defer_lookahead)):
        if steps and (defer_width is None or steps < 0):
            raise ValueError(
                f"method {name!r}: {field}= is a number of steps >= 0 for deferral "
                f"rows (with defer_width=), got {steps}"
            )
    if defer_hold_on and not defer_hold:
        raise ValueError(
            f"method {name!r}: defer_hold_on= names the dimensions that start a hold "
            f"(with defer_hold=), got {defer_hold_on} without a hold"
        )
    if expert_config is not None and not expert:
        raise ValueError(f"method {name!r}: expert_config= is for expert rows")
    if seeds and selection is None:
        raise ValueError(f"method {name!r}: seeds= is for BC rows (with selection=)")
    if selection is not None:
        return Agent(name, selection, bc, tuple(seeds), label, renderer, demos)
    if expert:
        return Expert(name, expert_config, label, renderer)
    if given:
        ((method, config),) = given.items()
        return FromStart(name, start, config, method=method, label=label, renderer=renderer)
    if fallback_of:
        handover = None
        if defer_width is not None:
            handover = HandoverConfig(defer_width, defer_lookahead, defer_hold, defer_hold_on)
        return Handover(name, fallback_of, handover, label, renderer)
    return View(name, masked_of or agents_of, bool(masked_of), renderer, label)
