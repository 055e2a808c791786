"""The task registry and the built-in tasks (CarRacing, then the rehabilitation pathway).

A task is one folder, ``safe_bc/tasks/<name>/``, whose ``SPEC`` (a :class:`TaskSpec`: env,
expert, observed costs, defaults) is registered with one line, ``register_task(SPEC)``.
Code that needs a task-specific value looks it up here (or, for a dataset, in its
``dataset.json``) rather than testing for a task. Importing any ``safe_bc.tasks`` module
runs this file first, so the built-ins are always registered. ``PerturbationConfig`` (the
type of ``TaskSpec.perturbation``; CarRacing's, ``mode="none"`` for a task without
perturbations) is re-exported for tasks defined elsewhere.
"""

from safe_bc.tasks import carracing, rehab
from safe_bc.tasks.carracing.perturb import PerturbationConfig
from safe_bc.tasks.env_config import EnvConfig
from safe_bc.tasks.factory import make_env
from safe_bc.tasks.lookup import (
    action_bounds,
    check_frames_renderer,
    check_net_fits_task,
    dataset_action_bounds,
    frames_renderer,
    with_task_eps,
)
from safe_bc.tasks.registry import (
    DEFAULT_TASK,
    ENTRY_POINTS,
    PLUGINS_VAR,
    TASKS,
    Bounds,
    Drawing,
    GymEnv,
    Task,
    TaskDefaults,
    TaskPluginError,
    TaskSpec,
    register_envs,
    register_task,
    spec_of,
    spec_of_env,
    spec_of_expert,
    task_defaults,
    task_of,
)

# the built-in tasks, one line each (registration order is TASKS' order)
register_task(carracing.SPEC)
register_task(rehab.SPEC)

ENV_IDS: tuple[str, ...] = tuple(g.id for spec in TASKS.values() for g in spec.gym_envs)
"""The gymnasium ids that ``import safe_bc`` (or :func:`register_envs`) registers: the
built-in tasks' (a task registered later registers its own)."""

__all__ = [
    "DEFAULT_TASK",
    "ENTRY_POINTS",
    "ENV_IDS",
    "PLUGINS_VAR",
    "TASKS",
    "Bounds",
    "Drawing",
    "EnvConfig",
    "GymEnv",
    "PerturbationConfig",
    "Task",
    "TaskDefaults",
    "TaskPluginError",
    "TaskSpec",
    "action_bounds",
    "check_frames_renderer",
    "check_net_fits_task",
    "dataset_action_bounds",
    "frames_renderer",
    "make_env",
    "register_envs",
    "register_task",
    "spec_of",
    "spec_of_env",
    "spec_of_expert",
    "task_defaults",
    "task_of",
    "with_task_eps",
]
