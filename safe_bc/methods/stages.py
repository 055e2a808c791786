"""The study's stages: what a study can do to a trained agent before it is evaluated.

A study trial (and the final phase, for every candidate and training seed) first trains its
behaviour-cloning net; then every registered method (:data:`safe_bc.methods.METHODS`) whose
config the :class:`StudySpec` sets (:meth:`StudySpec.stages`) turns the agent so far into the
agent that is evaluated, in registry order. A method as a stage is its
:class:`~safe_bc.methods.MethodSpec` itself:

* ``name``: the ``StudySpec`` field holding its config for the built-in methods, else its key
  in ``StudySpec.stage_configs`` (:meth:`StudySpec.stage_base`; ``None``: the stage is off).
  Its fields are searchable as ``<name>.<field>`` keys (``prefix``; :func:`stage_of`).
* :func:`run_stage` runs it on a trained net, from a :class:`~safe_bc.methods.Start`.
* ``metrics``: the keys of its report values (trial table columns); ``summed`` of them add up
  over training seeds, the others are the first seed's (``reduce``).

``tests/test_stages.py`` walks every registered method (field, runner, metrics).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from safe_bc.methods import METHODS, MethodSpec, Start
from safe_bc.moved import names
from safe_bc.run_config import RunConfig


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
    """``method`` run from the trained net ``agent`` (a :class:`BCNet`) in the task's env: the
    improved agent's policy source and its report values.

    ``config`` is the stage's config with the trial's parameters and ``seed`` = the training
    seed, ``folder`` the stage's own resumable folder, ``parallel`` how the stage may spread
    rollouts over workers (:data:`safe_bc.methods.rounds.Parallel`; the distributed layer
    passes its Ray actors, so that a runner names no Ray)."""
    from safe_bc.bc.net import BCNet
    from safe_bc.tasks import task_defaults, task_of

    if not isinstance(agent, BCNet):
        raise TypeError(f"the {method.name} stage starts from a trained BCNet, got {type(agent)}")
    env = task_defaults(task_of(env_id)).env
    done = method.run(config, Start(agent, run_config, demos, env, parallel=parallel), folder)
    return done.policy, done.report


def stage_metrics() -> tuple[str, ...]:
    """Every registered method's report keys, in registry order (columns of the trial table),
    read when asked: a method registered after this module was imported is counted."""
    return tuple(k for m in METHODS.values() for k in m.metrics)


def stage_of(key: str) -> str | None:
    """The method whose search keys ``key`` belongs to (``None``: a ``RunConfig`` key).

    >>> stage_of("improve.cost_margin"), stage_of("selection.alpha")
    ('improve', None)
    """
    for name, method in METHODS.items():
        if key.startswith(method.prefix):
            return name
    return None


_moved = names(__name__)


def __getattr__(name: str) -> Any:
    if name == "STAGE_METRICS":  # the name earlier code imports: the live list
        return stage_metrics()
    return _moved(name)  # STAGES: the registry itself (safe_bc.moved.NAMES)
