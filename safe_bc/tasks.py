"""Per-task defaults: the env, expert, perturbation and encoding of each testbed."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

from safe_bc.data.codec import Encoding
from safe_bc.envs import EnvConfig
from safe_bc.experts.carracing import ExpertConfig
from safe_bc.experts.perturb import PerturbationConfig

Task = Literal["carracing", "rehab"]


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


def task_defaults(task: Task, renderer: Literal["fast", "stock"] = "fast") -> TaskDefaults:
    """Defaults of ``task`` (``carracing`` or ``rehab``)."""
    if task == "carracing":
        return TaskDefaults(
            env=EnvConfig("CarRacing-v3", renderer=renderer),
            expert=ExpertConfig(),
            perturbation=PerturbationConfig(),
            encoding="png",
        )
    if task == "rehab":
        from safe_bc.experts.rehab import GuidelineConfig

        return TaskDefaults(
            env=EnvConfig("safe_bc/RehabPathway-v0"),
            expert=GuidelineConfig(),
            perturbation=PerturbationConfig(mode="none"),
            encoding="vector",
        )
    raise ValueError(f"unknown task {task!r}: choose carracing or rehab")
