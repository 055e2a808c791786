"""Choose on selection tracks by a rule fixed in advance, then run fresh tracks.

A selection comparison evaluates candidate rows (handovers over an agent: a grid of
:class:`~safe_bc.handover.HandoverConfig`) on tracks no reported table uses. A :class:`Fresh`
comparison declares, as data, which selection comparison it follows and which rule picks its
rows (:class:`Rule`: a name from :data:`RULES` and its parameters); :func:`resolve` applies the
rule to the selection's table when the fresh comparison is about to run, and returns the
selection's comparison with its candidate rows replaced by the chosen ones and the fresh
tracks set.

:func:`track_clashes` is the ledger of track blocks: two tables on the same tracks of a task
must say so (the same runs folder, or ``shares_tracks_with``).

Pure: no files, no Ray; the caller reads the selection's table.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import pandas as pd

from safe_bc.compare.rows import Handover
from safe_bc.compare.spec import Comparison

RuleFn = Callable[..., list[Handover]]


BEYOND = "episodes_with_violation"
"""The table column counting a row's episodes beyond d_s (a step beyond it)."""


def _beyond(table: pd.DataFrame, row: Handover, column: str = BEYOND) -> int:
    return int(table.loc[row.name, column])


def smallest_safe_width(
    table: pd.DataFrame, candidates: Sequence[Handover], beyond: str = BEYOND
) -> list[Handover]:
    """Per agent handed over (candidates grouped by ``of``, in table order): the row of the
    smallest width with no selection episode beyond d_s, else the row of the largest width.
    ``beyond``: the column counting a row's episodes beyond d_s (e.g. the clinic's
    ``total_any_violating_session``, an outcome beyond it, the last one included)."""
    agents: dict[str, list[Handover]] = {}
    for r in candidates:
        agents.setdefault(r.of, []).append(r)
    picked = []
    for rows in agents.values():
        by_width = sorted(rows, key=lambda r: r.handover.width)  # type: ignore[union-attr]
        safe = [r for r in by_width if _beyond(table, r, beyond) == 0]
        picked.append(safe[0] if safe else by_width[-1])
    return picked


def least_deferred(
    table: pd.DataFrame, candidates: Sequence[Handover], burden: float
) -> list[Handover]:
    """Among the rows with no selection episode beyond d_s and a mean deferred share below
    ``burden``, the one with the smallest share (ties: table order); none: no row."""
    ok = [
        (float(table.loc[r.name, "deferred_share"]), i, r)
        for i, r in enumerate(candidates)
        if _beyond(table, r) == 0 and float(table.loc[r.name, "deferred_share"]) < burden
    ]
    return [min(ok, key=lambda x: x[:2])[2]] if ok else []


def best_lower_bound(
    table: pd.DataFrame, candidates: Sequence[Handover], burden: float, beyond: str = BEYOND
) -> list[Handover]:
    """Among the rows with no selection episode beyond d_s and a mean deferred share below
    ``burden``, the one with the highest lower bound of the paired reward interval against the
    table's reference (``d_reward_lo``); ties: fewer training env steps of the agent handed over
    (``env_steps`` of its ``of`` row), then table order; none: no row. ``beyond`` as in
    :func:`smallest_safe_width`."""

    def steps(r: Handover) -> float:
        value = table["env_steps"].get(r.of) if "env_steps" in table else None
        return float(value) if value is not None and value == value else 0.0

    ok = [
        (-float(table.loc[r.name, "d_reward_lo"]), steps(r), i, r)
        for i, r in enumerate(candidates)
        if _beyond(table, r, beyond) == 0 and float(table.loc[r.name, "deferred_share"]) < burden
    ]
    return [min(ok, key=lambda x: x[:3])[3]] if ok else []


RULES: dict[str, RuleFn] = {
    "smallest_safe_width": smallest_safe_width,
    "least_deferred": least_deferred,
    "best_lower_bound": best_lower_bound,
}
"""Rule name -> ``rule(table, candidates, **params)``: the chosen candidates (possibly none).
``table`` is the selection's table indexed by row name; ``candidates`` its deferral rows, in
table order."""


@dataclass(frozen=True)
class Rule:
    """A rule of :data:`RULES` with its parameters."""

    name: str
    """Key of :data:`RULES`."""
    params: Mapping[str, Any] = field(default_factory=dict)
    """Keyword arguments of the rule (e.g. ``{"burden": 0.05}``)."""
    note: str = ""
    """Text the fresh comparison's note puts in place of ``{rule}`` when this rule picked (or,
    when no rule picked, when it is the last one)."""

    def __post_init__(self) -> None:
        if self.name not in RULES:
            raise ValueError(f"unknown rule {self.name!r}; rules: {', '.join(RULES)}")


@dataclass(frozen=True)
class Fresh:
    """A fresh-track comparison: the rows a rule picks on a selection comparison's table,
    beside the selection's other rows, on other tracks."""

    name: str
    """Stem of the outputs (:attr:`safe_bc.compare.spec.Comparison.name`)."""
    follows: str
    """The selection comparison (its key in the same family)."""
    rules: tuple[Rule, ...]
    """Tried in order: the first that picks a row decides; none picks: no deferral row."""
    eval_seed: int
    """The fresh block of held-out track seeds."""
    episodes: int | None = None
    """Tracks of the block (``None``: the selection's number)."""
    title: str = ""
    """Markdown heading."""
    note: str = ""
    """What the rows mean; ``{rule}`` is replaced by the deciding rule's :attr:`Rule.note`."""
    shares_tracks_with: tuple[str, ...] = ()
    """Tables (``OUT/name``) that may use the same tracks (the ledger's declared sharing)."""

    def __post_init__(self) -> None:
        if not self.rules:
            raise ValueError(f"fresh comparison {self.name!r}: no rule")


def candidates(selection: Comparison) -> list[Handover]:
    """The selection's candidate rows: its handovers with a :class:`HandoverConfig`."""
    return [m for m in selection.methods if isinstance(m, Handover) and m.handover is not None]


def choose(fresh: Fresh, selection: Comparison, table: pd.DataFrame) -> tuple[Rule, list[Handover]]:
    """The deciding rule and the rows it picks on ``table`` (the selection's table, one row
    per method, a ``method`` column)."""
    indexed = table.set_index("method")
    rows = candidates(selection)
    missing = [r.name for r in rows if r.name not in indexed.index]
    if missing:
        raise ValueError(
            f"fresh comparison {fresh.name!r}: the table of {selection.name!r} lacks rows {missing}"
        )
    for rule in fresh.rules:
        picked = RULES[rule.name](indexed, rows, **rule.params)
        if picked:
            return rule, picked
    return fresh.rules[-1], []


def resolve(fresh: Fresh, selection: Comparison, table: pd.DataFrame) -> Comparison:
    """The comparison ``fresh`` runs: ``selection`` with its candidate rows replaced by those
    the rules pick on ``table``, on ``fresh``'s tracks."""
    rule, picked = choose(fresh, selection, table)
    changes: dict[str, Any] = {
        "name": fresh.name,
        "eval_seed": fresh.eval_seed,
        "title": fresh.title,
        "note": fresh.note.replace("{rule}", rule.note),
        "shares_tracks_with": fresh.shares_tracks_with,
    }
    if fresh.episodes is not None:
        changes["episodes"] = fresh.episodes
    return selection.with_deferral(picked, **changes)


def track_clashes(
    tables: Iterable[Comparison], seeds: Callable[[Comparison], Iterable[int]]
) -> list[str]:
    """The ledger's violations: pairs of tables with a track in common (the same task and env
    seed, ``seeds(table)``), neither in the other's runs folder nor declared by
    ``shares_tracks_with`` (either side, by ``OUT/name``). One line per pair."""
    rows = []
    for c in tables:
        rows.append((f"{c.out}/{c.name}", c, {(c.task, s) for s in seeds(c)}))
    out = []
    for (a, ca, sa), (b, cb, sb) in itertools.combinations(rows, 2):
        common = sa & sb
        same_runs = ca.out == cb.out and (ca.runs or ca.name) == (cb.runs or cb.name)
        declared = b in ca.shares_tracks_with or a in cb.shares_tracks_with
        if common and not same_runs and not declared:
            out.append(f"{a} and {b} share {len(common)} tracks (task {ca.task}) undeclared")
    return out
