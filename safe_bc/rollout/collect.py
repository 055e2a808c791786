"""What one demonstration episode is: env + expert + perturbation + seeds (no Ray, no I/O)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import gymnasium as gym

from safe_bc.data.codec import Encoding
from safe_bc.data.episode import Episode
from safe_bc.policy import Policy
from safe_bc.rollout.episode import run_episode
from safe_bc.seeds import demo_seed, episode_rng
from safe_bc.tasks.carracing.expert import ExpertConfig
from safe_bc.tasks.carracing.perturb import Perturbation, PerturbationConfig
from safe_bc.tasks.env_config import EnvConfig
from safe_bc.tasks.factory import make_env
from safe_bc.tasks.registry import DEFAULT_TASK, TaskSpec, spec_of, spec_of_expert, task_defaults


@dataclass(frozen=True)
class CollectConfig:
    """A demonstration collection: which episodes, made how, by how many workers."""

    episodes: int = 5
    """Number of expert episodes (the paper used 4692 pairs: ~5 CarRacing episodes)."""
    workers: int = 2
    """Persistent rollout actors running in parallel."""
    seed: int = 0
    """Collection seed: fixes every episode's track and noise."""
    env: EnvConfig = field(default_factory=EnvConfig)
    """The environment."""
    expert: Any = field(default_factory=ExpertConfig)
    """The expert's configuration (:class:`ExpertConfig` for CarRacing)."""
    perturbation: PerturbationConfig = field(default_factory=PerturbationConfig)
    """Perturbation of the executed action (the recorded label stays the expert's)."""
    max_steps: int | None = None
    """Cap on steps per episode (``None``: the env's time limit)."""
    encoding: Encoding = "png"
    """Observation encoding in Parquet (``vector`` for non-image envs)."""

    def __post_init__(self) -> None:
        if self.episodes < 1:
            raise ValueError(f"episodes must be >= 1, got {self.episodes}")
        if self.workers < 1:
            raise ValueError(f"workers must be >= 1, got {self.workers}")
        if self.seed < 0:
            raise ValueError(f"seed must be >= 0, got {self.seed}")
        if self.max_steps is not None and self.max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {self.max_steps}")
        if self.encoding not in ("png", "raw", "vector"):
            raise ValueError(f"encoding must be png, raw or vector, got {self.encoding!r}")
        task = spec_of(self.env.env_id)
        if (task.encoding == "vector") != (self.encoding == "vector"):
            raise ValueError(
                f"encoding {self.encoding!r} does not fit {self.env.env_id} observations"
            )
        if not task.perturbable and self.perturbation.mode != "none":
            raise ValueError(
                f"perturbation mode {self.perturbation.mode!r} acts on CarRacing's "
                f"(steer, gas, brake); use mode='none' for {self.env.env_id}"
            )

    @classmethod
    def for_task(cls, task: TaskSpec, **overrides: Any) -> CollectConfig:
        """The task's default demonstration collection; ``overrides`` set other fields
        (``episodes``, ``workers``, ``seed``, ``max_steps``, ``encoding``)."""
        fields = {
            "episodes": task.episodes,
            "env": task.env,
            "expert": task.expert,
            "perturbation": task.perturbation,
            "encoding": task.encoding,
        }
        return cls(**{**fields, **overrides})


def config_dict(cfg: Any) -> dict[str, Any]:
    """A dataclass config as a JSON-able dict with its type name."""
    return {"type": type(cfg).__name__, **asdict(cfg)}


def expert_config_from_dict(data: dict[str, Any]) -> Any:
    """Inverse of :func:`config_dict` for expert configs (as stored in ``dataset.json``; a
    record without a type is the default task's, from before types were recorded)."""
    data = dict(data)
    kind = data.pop("type", None) or task_defaults(DEFAULT_TASK).expert_type
    cls = spec_of_expert(kind).expert_type
    return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in data.items()})


def stored_expert_config(demos: Path) -> Any:
    """The expert configuration recorded in a demonstration set's ``dataset.json``."""
    from safe_bc.data.store import read_meta

    return expert_config_from_dict(read_meta(demos).expert)


def expert_for(demos: str | Path, env_id: str) -> Any:
    """The expert config that made ``demos`` (its ``dataset.json``), else the task's default."""
    from safe_bc.data.store import read_meta
    from safe_bc.tasks import task_defaults, task_of

    default = task_defaults(task_of(env_id)).expert
    try:
        recorded = read_meta(Path(demos)).expert or {}
    except Exception:  # a dataset without a readable record: the task's expert
        return default
    names = {f.name for f in fields(default)}
    return type(default)(**{k: v for k, v in recorded.items() if k in names})


def build_expert(cfg: Any) -> Policy:
    """The expert policy for an expert config (its task's ``build_expert``)."""
    try:
        spec = spec_of_expert(type(cfg))
    except ValueError:
        raise TypeError(f"no expert for config type {type(cfg).__name__}") from None
    return spec.build_expert(cfg)


class EpisodeMaker:
    """Holds one env and one expert; makes demonstration episodes by id.

    The same ``(config.seed, episode_id)`` always gives the same episode, whichever
    process makes it.
    """

    def __init__(self, config: CollectConfig) -> None:
        self.config = config
        self.env: gym.Env = make_env(config.env)
        self.expert = build_expert(config.expert)
        self.perturbation = (
            Perturbation(config.perturbation) if config.perturbation.mode != "none" else None
        )

    def make(self, episode_id: int) -> Episode:
        """Roll out episode ``episode_id`` of the collection."""
        rng = episode_rng(self.config.seed, episode_id)
        return run_episode(
            self.env,
            self.expert,
            demo_seed(self.config.seed, episode_id),
            rng,
            episode_id=episode_id,
            perturbation=self.perturbation,
            max_steps=self.config.max_steps,
        )

    def close(self) -> None:
        """Release the env."""
        self.env.close()


def env_facts(
    config: CollectConfig,
) -> tuple[tuple[int, ...], tuple[str, ...], tuple[tuple[float, ...], tuple[float, ...]]]:
    """``(observation shape, safety dimension names, (action low, action high))`` of the
    collection's env (built once)."""
    env = make_env(config.env)
    try:
        shape = tuple(int(x) for x in env.observation_space.shape)
        space = env.action_space
        bounds = tuple(float(x) for x in space.low), tuple(float(x) for x in space.high)
        return shape, tuple(env.get_wrapper_attr("safety_dims")), bounds
    finally:
        env.close()
