"""The study stage registry: what a study can do to a trained agent before it is evaluated.

A study trial (and the final phase, for every candidate and training seed) first trains its
behaviour-cloning net; then every *stage* whose config is set on the :class:`StudySpec`
turns the agent so far into the agent that is evaluated, in registry order. A stage is one
entry here plus one module with its runner:

* ``field``: the ``StudySpec`` field holding the stage's config (``None``: the stage is off).
  Its fields are searchable as ``<field>.<name>`` keys of the study's space.
* ``runner``: ``"module:function"`` (imported only when the stage runs, so reading a study file
  imports no torch), called as
  ``runner(config, agent, run_config, demos, env_id, folder, parallel=parallel)`` and
  returning ``(policy_source, report_values)``: ``config`` is the stage's config with the
  trial's parameters and ``seed`` = the training seed, ``agent`` the trained
  :class:`~safe_bc.bc.BCNet` (for a later stage, the previous stage's agent), ``folder`` the
  stage's own resumable folder, ``parallel`` how the stage may spread rollouts over workers
  (:data:`safe_bc.rounds.Parallel`; the distributed layer passes its Ray actors, so that a
  runner names no Ray).
* ``metrics``: the keys of ``report_values`` (trial table columns); ``summed`` of them add up
  over training seeds, the others are the first seed's.

``tests/test_stages.py`` walks every entry (field, runner, metrics).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Stage:
    """One registry entry (see the module docstring)."""

    field: str
    """``StudySpec`` field with the stage's config; also the search-key prefix."""
    runner: str
    """``"module:function"`` of the runner."""
    metrics: tuple[str, ...]
    """Report keys the runner returns (columns of the trial table)."""
    summed: tuple[str, ...] = ()
    """Of :attr:`metrics`, those summed over training seeds (the rest: the first seed's)."""
    label: str = ""
    """What the final phase's progress line calls it (e.g. ``"improving"``)."""

    @property
    def prefix(self) -> str:
        """Search-space keys of this stage start with it (``"improve."``)."""
        return f"{self.field}."

    def load(self) -> Callable[..., tuple[Any, dict[str, float]]]:
        """The runner function (imports its module)."""
        module, _, name = self.runner.partition(":")
        return getattr(importlib.import_module(module), name)

    def reduce(self, per_seed: Sequence[Mapping[str, float]]) -> dict[str, float]:
        """One report from every training seed's values: :attr:`summed` keys added up, the
        others the first seed's.

        >>> STAGES["improve"].reduce([{"improve_seconds": 2.0, "improve_kept_iteration": 5},
        ...                           {"improve_seconds": 3.0, "improve_kept_iteration": 7}])
        {'improve_seconds': 5.0, 'improve_kept_iteration': 5}
        """
        out = dict(per_seed[0])
        for key in self.summed:
            out[key] = sum(v[key] for v in per_seed)
        return out


STAGES: dict[str, Stage] = {
    "improve": Stage(
        field="improve",
        runner="safe_bc.improve.stage:run_stage",
        metrics=("improve_seconds", "improve_kept_iteration"),
        summed=("improve_seconds",),
        label="improving",
    ),
    "queries": Stage(
        field="queries",
        runner="safe_bc.queries.stage:run_stage",
        metrics=("queries_total", "queries_per_episode", "queries_seconds"),
        summed=("queries_total", "queries_seconds"),
        label="querying the expert",
    ),
    "selfimprove": Stage(
        field="selfimprove",
        runner="safe_bc.selfimprove.stage:run_stage",
        metrics=("selfimprove_accepted_rounds", "selfimprove_kept_steps", "selfimprove_seconds"),
        summed=("selfimprove_kept_steps", "selfimprove_seconds"),
        label="self-imitating",
    ),
}
"""Stage name -> :class:`Stage`, in the order stages run."""

STAGE_METRICS: tuple[str, ...] = tuple(k for s in STAGES.values() for k in s.metrics)
"""Every stage's report keys, in registry order."""


def stage_of(key: str) -> str | None:
    """The stage whose search keys ``key`` belongs to (``None``: a ``RunConfig`` key).

    >>> stage_of("improve.cost_margin"), stage_of("selection.alpha")
    ('improve', None)
    """
    for name, stage in STAGES.items():
        if key.startswith(stage.prefix):
            return name
    return None
