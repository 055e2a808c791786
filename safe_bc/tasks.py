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
    episodes: int
    """Episodes of the default demonstration set (~4,700 pairs, like the paper's)."""
    eps: float
    """Default critical-zone width, in the cost's units."""
    demos: str
    """Where the default demonstration set lives."""
    results: str
    """Where the task's result tables and figures go."""

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


def task_defaults(task: Task, renderer: Literal["fast", "stock"] = "fast") -> TaskDefaults:
    """Defaults of ``task`` (``carracing`` or ``rehab``)."""
    if task == "carracing":
        return TaskDefaults(
            env=EnvConfig("CarRacing-v3", renderer=renderer),
            expert=ExpertConfig(),
            perturbation=PerturbationConfig(),
            encoding="png",
            episodes=5,
            eps=2.0,
            demos="data/demos",
            results="results",
        )
    if task == "rehab":
        from safe_bc.experts.rehab import GuidelineConfig

        return TaskDefaults(
            env=EnvConfig("safe_bc/RehabPathway-v0"),
            expert=GuidelineConfig(),
            perturbation=PerturbationConfig(mode="none"),
            encoding="vector",
            episodes=150,
            eps=0.05,
            demos="data/rehab_demos",
            results="results/rehab",
        )
    raise ValueError(f"unknown task {task!r}: choose carracing or rehab")


def task_of(env_id: str) -> Task:
    """The task name of an env id."""
    return "carracing" if env_id == "CarRacing-v3" else "rehab"


def action_bounds(env_config: EnvConfig) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """``(low, high)`` of the env's Box action space, for squashing the policy's outputs."""
    from safe_bc.envs import make_env

    env = make_env(env_config)
    try:
        space = env.action_space
        return tuple(float(x) for x in space.low), tuple(float(x) for x in space.high)
    finally:
        env.close()
