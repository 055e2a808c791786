"""The task registry: per testbed, its env, expert, default collection, action bounds and
safety dimensions. Code that needs a task-specific value looks it up here (or, for a
dataset, in its ``dataset.json``) rather than testing for CarRacing."""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, get_args

import numpy as np

from safe_bc.data.codec import Encoding
from safe_bc.envs import SAFETY_DIMS, EnvConfig
from safe_bc.envs.factory import CARRACING_ID, REHAB_ID, Renderer
from safe_bc.experts.carracing import ExpertConfig
from safe_bc.experts.perturb import PerturbationConfig
from safe_bc.selection import DEFAULT_EPS

Task = Literal["carracing", "rehab"]
TASKS: tuple[Task, ...] = get_args(Task)
DEFAULT_TASK: Task = TASKS[0]
"""The task a command runs when none is named (the CarRacing testbed)."""

Bounds = tuple[tuple[float, ...], tuple[float, ...]]
"""``(low (A,), high (A,))`` of a Box action space."""


@dataclass(frozen=True)
class TaskDefaults:
    """What a task collects with unless told otherwise."""

    env: EnvConfig
    """The environment."""
    expert: Any
    """The expert's configuration."""
    perturbation: PerturbationConfig
    """The default perturbation of the executed actions."""
    encoding: Encoding
    """Observation encoding in Parquet."""
    episodes: int
    """Episodes of the default demonstration set (~4,700 pairs, like the paper's)."""
    eps: float
    """Default critical-zone width, in the cost's units."""
    demos: str
    """Where the default demonstration set lives."""
    results: str
    """Where the task's result tables and figures go."""
    action_bounds: Bounds
    """``(low, high)`` of the env's action space (the policy's outputs are squashed to it)."""
    safety_dims: tuple[str, ...]
    """Names of the env's safety dimensions, in the order of its costs."""
    paper_table1: bool
    """Whether the paper reports a Table 1 for this task (``reproduce`` compares with it)."""
    observed_costs: Callable[[np.ndarray], np.ndarray]
    """Safety costs as measured from a batch of observations, ``(B, *obs) -> (B, S)``: what a
    deployed policy can see (the shield and the improvement's cost signal use it)."""

    def collect_config(self, **overrides: Any) -> Any:
        """The task's default demonstration collection; ``overrides`` set other fields
        (``episodes``, ``workers``, ``seed``, ``max_steps``, ``encoding``)."""
        from safe_bc.collection import CollectConfig

        fields = {
            "episodes": self.episodes,
            "env": self.env,
            "expert": self.expert,
            "perturbation": self.perturbation,
            "encoding": self.encoding,
        }
        return CollectConfig(**{**fields, **overrides})


def _carracing(renderer: Renderer) -> TaskDefaults:
    from safe_bc.envs.safety import frame_costs

    return TaskDefaults(
        env=EnvConfig(CARRACING_ID, renderer=renderer),
        expert=ExpertConfig(),
        perturbation=PerturbationConfig(),
        encoding="png",
        episodes=5,
        eps=DEFAULT_EPS,
        demos="data/demos",
        results="results",
        action_bounds=((-1.0, 0.0, 0.0), (1.0, 1.0, 1.0)),  # steer, gas, brake
        safety_dims=SAFETY_DIMS,
        paper_table1=True,
        observed_costs=frame_costs,
    )


def _rehab(renderer: Renderer) -> TaskDefaults:
    from safe_bc.envs.rehab import REHAB_SAFETY_DIMS, observed_costs
    from safe_bc.experts.rehab import GuidelineConfig

    return TaskDefaults(
        env=EnvConfig(REHAB_ID),
        expert=GuidelineConfig(),
        perturbation=PerturbationConfig(mode="none"),
        encoding="vector",
        episodes=150,
        eps=0.05,
        demos="data/rehab_demos",
        results="results/rehab",
        action_bounds=((-1.0, -1.0), (1.0, 1.0)),
        safety_dims=REHAB_SAFETY_DIMS,
        paper_table1=False,
        observed_costs=observed_costs,
    )


REGISTRY: dict[Task, Callable[[Renderer], TaskDefaults]] = {
    "carracing": _carracing,
    "rehab": _rehab,
}
"""Task name -> its entry. Adding a task: one entry here (and its env, expert and cost
modules); ``tests/test_tasks.py`` walks every entry."""


@functools.cache
def task_defaults(task: Task, renderer: Renderer = "fast") -> TaskDefaults:
    """Defaults of ``task`` (a key of :data:`REGISTRY`; frozen, so built once)."""
    if task not in REGISTRY:
        raise ValueError(f"unknown task {task!r}: choose {' or '.join(REGISTRY)}")
    return REGISTRY[task](renderer)


@functools.cache
def task_of(env_id: str) -> Task:
    """The task whose env is ``env_id`` (cached: the shield looks it up every step)."""
    for task in TASKS:
        if task_defaults(task).env.env_id == env_id:
            return task
    raise ValueError(f"no task uses env {env_id!r} (known: {', '.join(TASKS)})")


def check_net_fits_task(
    obs_shape: tuple[int, ...], action_dim: int, env_id: str, where: Any
) -> None:
    """A net trained for one task must not be run on another: its observation rank (frames
    or vectors) and action count must be the task's. Checked before any env is started.

    Raises:
        ValueError: one line naming ``where`` (the checkpoint) and both shapes.
    """
    task = task_defaults(task_of(env_id))
    rank, dims = (1 if task.encoding == "vector" else 3), len(task.action_bounds[0])
    if len(obs_shape) != rank or action_dim != dims:
        kind = "vectors" if rank == 1 else "frames"
        raise ValueError(
            f"{where}: its net takes observations of shape {tuple(obs_shape)} and gives "
            f"{action_dim} action(s), but it names {env_id} ({kind}, {dims} action(s)); the "
            "checkpoint's env_id is not the task it was trained on"
        )


def dataset_action_bounds(root: str | Path) -> Bounds:
    """The action bounds of the dataset at ``root``: from its ``dataset.json``, or, for a
    dataset collected before the bounds were recorded there, from its task's entry."""
    from safe_bc.data.store import read_meta

    meta = read_meta(Path(root))
    if meta.action_bounds is not None:
        return meta.action_bounds
    return task_defaults(task_of(meta.env_id)).action_bounds


def action_bounds(env_config: EnvConfig) -> Bounds:
    """``(low, high)`` of the env's Box action space, read from a built env."""
    from safe_bc.envs import make_env

    env = make_env(env_config)
    try:
        space = env.action_space
        return tuple(float(x) for x in space.low), tuple(float(x) for x in space.high)
    finally:
        env.close()
