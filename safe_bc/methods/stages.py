"""The study's stages: what a study can do to a trained agent before it is evaluated.

A study trial (and the final phase, for every candidate and training seed) first trains its
behaviour-cloning net; then every *stage* whose config the :class:`StudySpec` sets turns the
agent so far into the agent that is evaluated, in registry order. Every registered method
(:data:`safe_bc.methods.METHODS`) is a stage; :data:`STAGES` is their view as stages:

* ``field``: the method's name; the ``StudySpec`` field holding its config for the built-in
  methods, else its key in ``StudySpec.stage_configs`` (:meth:`StudySpec.stage_base`;
  ``None``: the stage is off). Its fields are searchable as ``<field>.<name>`` keys.
* ``load()``: the stage runner, called as ``runner(config, agent, run_config, demos, env_id,
  folder, parallel=parallel)`` and returning ``(policy_source, report_values)``: ``config`` is
  the stage's config with the trial's parameters and ``seed`` = the training seed, ``agent``
  the trained :class:`~safe_bc.bc.BCNet`, ``folder`` the stage's own resumable folder,
  ``parallel`` how the stage may spread rollouts over workers
  (:data:`safe_bc.methods.rounds.Parallel`;
  the distributed layer passes its Ray actors, so that a runner names no Ray). It runs the
  method's runner from a :class:`~safe_bc.methods.Start` (:func:`run_stage`).
* ``metrics``: the keys of ``report_values`` (trial table columns); ``summed`` of them add up
  over training seeds, the others are the first seed's.

``tests/test_stages.py`` walks every entry (field, runner, metrics).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from safe_bc.methods import METHODS, MethodSpec, Start
from safe_bc.run_config import RunConfig


@dataclass(frozen=True)
class Stage:
    """A registered method as a study stage (see the module docstring)."""

    method: MethodSpec
    """The method."""

    @property
    def field(self) -> str:
        """The method's name: its ``StudySpec`` field or ``stage_configs`` key, and the
        search-key prefix."""
        return self.method.name

    @property
    def metrics(self) -> tuple[str, ...]:
        """Report keys the runner returns (columns of the trial table)."""
        return self.method.metrics

    @property
    def summed(self) -> tuple[str, ...]:
        """Of :attr:`metrics`, those summed over training seeds (the rest: the first seed's)."""
        return self.method.summed

    @property
    def label(self) -> str:
        """What the final phase's progress line calls it (e.g. ``"improving"``)."""
        return self.method.label

    @property
    def prefix(self) -> str:
        """Search-space keys of this stage start with it (``"improve."``)."""
        return f"{self.field}."

    def load(self) -> Callable[..., tuple[Any, dict[str, float]]]:
        """The stage runner (:func:`run_stage` bound to the method)."""
        return functools.partial(run_stage, self.method)

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


def run_stage(
    method: MethodSpec,
    config: Any,
    agent: Any,
    run_config: RunConfig,
    demos: str,
    env_id: str,
    folder: Path,
    *,
    parallel: Any = None,
) -> tuple[Any, dict[str, float]]:
    """``method`` run from the trained net ``agent`` (a :class:`BCNet`) in the task's env
    (``parallel``: :attr:`safe_bc.methods.Start.parallel`): the improved agent's policy source
    and its report values."""
    from safe_bc.bc.net import BCNet
    from safe_bc.tasks import task_defaults, task_of

    if not isinstance(agent, BCNet):
        raise TypeError(f"the {method.name} stage starts from a trained BCNet, got {type(agent)}")
    env = task_defaults(task_of(env_id)).env
    done = method.run(config, Start(agent, run_config, demos, env, parallel=parallel), folder)
    return done.policy, done.report


class _Stages(Mapping[str, Stage]):
    """Every registered method as a :class:`Stage`, in registration order (a live view:
    a method registered later is a stage too)."""

    def __getitem__(self, name: str) -> Stage:
        return Stage(METHODS[name])

    def __iter__(self) -> Iterator[str]:
        return iter(list(METHODS))

    def __len__(self) -> int:
        return len(METHODS)


STAGES: Mapping[str, Stage] = _Stages()
"""Stage name -> :class:`Stage`, in the order stages run."""


def stage_metrics() -> tuple[str, ...]:
    """Every registered stage's report keys, in registry order (columns of the trial table),
    read when asked: a method registered after this module was imported is counted."""
    return tuple(k for s in STAGES.values() for k in s.metrics)


def __getattr__(name: str) -> Any:
    if name == "STAGE_METRICS":  # the name earlier code imports: the live list
        return stage_metrics()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def stage_of(key: str) -> str | None:
    """The stage whose search keys ``key`` belongs to (``None``: a ``RunConfig`` key).

    >>> stage_of("improve.cost_margin"), stage_of("selection.alpha")
    ('improve', None)
    """
    for name, stage in STAGES.items():
        if key.startswith(stage.prefix):
            return name
    return None
