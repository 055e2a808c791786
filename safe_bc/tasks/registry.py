"""The task registry: ``TASKS``, name -> :class:`TaskSpec`, filled by :func:`register_task`.

A task is one folder (``safe_bc/tasks/<name>/``: its env, expert, observed costs and
defaults) and one call, ``register_task(SPEC)``. Everything task-specific is read from here
(or, for a dataset, from its ``dataset.json``): env ids, :func:`safe_bc.tasks.make_env`, the
experts a dataset can name, what a collection may be. A task defined outside the package is
found in every process (Ray workers included) through an entry point of the
``safe_bc.tasks`` group declared by the package that holds it (``lane = "lane_task:SPEC"``
under ``[project.entry-points."safe_bc.tasks"]``), or through its module named in the
``SAFE_BC_TASKS`` environment variable (comma-separated); lookups load them on a miss. A
plug-in that cannot be loaded is one :class:`TaskPluginError` line naming it.
"""

from __future__ import annotations

import functools
import importlib
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np

from safe_bc.tasks.env_config import DEFAULT_RENDERER, EnvConfig, Renderer, canonical_renderer

if TYPE_CHECKING:
    from safe_bc.data.codec import Encoding
    from safe_bc.policy import Policy
    from safe_bc.tasks.carracing.perturb import PerturbationConfig

Task = str
"""A registered task's name (a key of :data:`TASKS`)."""
DEFAULT_TASK: Task = "carracing"
"""The task a command runs when none is named (the CarRacing testbed)."""
PLUGINS_VAR = "SAFE_BC_TASKS"
"""Environment variable naming modules that register further tasks (comma-separated)."""
ENTRY_POINTS = "safe_bc.tasks"
"""Entry-point group of task plug-ins: each entry names a :class:`TaskSpec` (``module:SPEC``,
registered when loaded) or a module that registers its tasks itself."""


class TaskPluginError(ValueError):
    """A task plug-in (entry point or ``SAFE_BC_TASKS`` module) that cannot be loaded."""


Bounds = tuple[tuple[float, ...], tuple[float, ...]]
"""``(low (A,), high (A,))`` of a Box action space."""


@dataclass(frozen=True)
class GymEnv:
    """One gymnasium id a task registers (``gym.register``'s arguments)."""

    id: str
    """The gymnasium id."""
    entry_point: str | Callable[..., gym.Env]
    """``"module:Class"`` (imported on first ``gym.make``) or a callable."""
    max_episode_steps: int | None = None
    """Gymnasium's ``TimeLimit``; ``None``: none."""
    reward_threshold: float | None = None
    """Gymnasium's ``reward_threshold``."""

    def register(self) -> None:
        """``gym.register`` this id unless it is registered already."""
        if self.id not in gym.registry:
            gym.register(
                id=self.id,
                entry_point=self.entry_point,
                max_episode_steps=self.max_episode_steps,
                reward_threshold=self.reward_threshold,
            )


def gym_make(config: EnvConfig) -> gym.Env:
    """``gym.make(config.env_id)`` with the config's time limit: a task's env built as
    registered (the env itself meets the info contract)."""
    kwargs = {}
    if config.max_episode_steps is not None:
        kwargs["max_episode_steps"] = config.max_episode_steps
    return gym.make(config.env_id, **kwargs)


@dataclass(frozen=True)
class Drawing:
    """How ``safe-bc render`` draws a task's episodes (:mod:`safe_bc.render` does the rest:
    upscaling, the critical-zone colours, border, header, video and track map). A task
    without one cannot be rendered."""

    overlay: Callable[[np.ndarray, np.ndarray, Sequence[tuple[int, int, int]], int], None]
    """``(upscaled frame, safety (S,), one RGB colour per dimension, scale)``: draws the
    safety readings over the upscaled frame in place (CarRacing: the three rays)."""
    caption: Callable[[np.ndarray], str]
    """``safety (S,) -> text``: the reading in a frame's header line."""
    position: Callable[[gym.Env], tuple[float, float]]
    """Where the agent is in the world now (the track map's path)."""
    ground: Callable[[gym.Env], list[np.ndarray]]
    """The world's polygons, ``(n, 2)`` each (the track map's background)."""
    unit: str
    """Unit of the safety distances (``closest 3.2 px``)."""
    closest: str
    """What the closest distance is measured to, with its unit (``px to the grass``)."""
    scale_label: str
    """Label of the track map's colour scale."""


@dataclass(frozen=True)
class TaskSpec:
    """One task: its env, its expert, its observed costs and what it collects with unless
    told otherwise."""

    name: Task
    """Key in :data:`TASKS` (``--env`` on the command line)."""
    env: EnvConfig
    """The default environment; its ``env_id`` names the task's env everywhere."""
    gym_envs: tuple[GymEnv, ...]
    """Gymnasium ids the task registers (``register_task`` and ``import safe_bc`` do)."""
    expert: Any
    """The expert's default configuration: a frozen dataclass whose type is the task's
    expert config type (``dataset.json`` records it by type name)."""
    build_expert: Callable[[Any], Policy]
    """Expert config -> the expert policy."""
    perturbation: PerturbationConfig
    """The default perturbation of the executed actions."""
    encoding: Encoding
    """Observation encoding in Parquet: ``vector`` for vector observations, ``png``/``raw``
    for frames."""
    episodes: int
    """Episodes of the default demonstration set."""
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
    observed_costs: Callable[[np.ndarray], np.ndarray]
    """Safety costs as measured from a batch of observations, ``(B, *obs) -> (B, S)``: what a
    deployed policy can see (the shield and the improvement's cost signal use it)."""
    make_env: Callable[[EnvConfig], gym.Env] = gym_make
    """Builds the env with its costs in ``info`` (default :func:`gym_make`)."""
    perturbable: bool = False
    """Whether the (steer, gas, brake) action perturbations apply (else only ``none``)."""
    has_renderer: bool = False
    """Whether ``EnvConfig.renderer`` picks how the env draws (else it stays the default)."""
    paper_table1: bool = False
    """Whether the paper reports a Table 1 for this task (``reproduce`` compares with it)."""
    drawing: Drawing | None = None
    """How ``safe-bc render`` draws its episodes; ``None``: it cannot be rendered."""
    selfimprove: tuple[tuple[str, Any], ...] = ()
    """The self-imitation settings this task's measurements chose (``(field, value)`` pairs of
    :class:`safe_bc.methods.selfimprove.config.SelfImproveConfig`: ``rounds``, ``pushes``,
    ``kept_in``), taken where a config leaves them at ``None``; empty: none measured (such a
    config must set them)."""
    cost_margin: float = 0.0
    """The improvement's margin inside ``d_s`` in the task's cost units
    (``ImproveConfig.cost_margin`` left at ``None``): the Lagrangian charges steps beyond
    ``d_s - cost_margin``."""
    handover: Any = None
    """The critical-zone handover a recommender of this task uses by default (a
    :class:`safe_bc.handover.HandoverConfig`, in the cost's units, chosen by a committed
    measurement on the task's selection tracks); ``None``: none measured yet."""
    safety_units: tuple[str, ...] = ()
    """Per safety dimension (``safety_dims`` order), the unit its distance and cost are
    measured in, as figures label their axes (CarRacing: ``px``); empty: ``cost units``."""
    safer_actions: tuple[int, ...] | None = None
    """Per action component, the sign of the direction in which no safety cost rises
    (``-1``: a lower value is safer, ``+1``: a higher one), what a handover with
    ``fallback="cap"`` needs; ``None``: the task has no such direction (CarRacing's steering)."""
    validation_episodes: int = 0
    """Episodes a study of this task holds out for its curves' validation loss by default
    (``StudySpec.validation_episodes``), chosen by a committed measurement of how much the
    recorded loss spreads with the held-out set (``results/validation_size/``); 0: none
    measured, so a study records the training loss only unless it is told a size."""
    episode_name: str = "episode"
    """What one episode is called in messages and reports, singular (CarRacing: ``track``,
    rehab: ``patient``); :attr:`episodes_name` is its plural."""
    metrics: tuple[str, ...] = ()
    """The task's own metrics: entries of :data:`safe_bc.metrics.REGISTRY` that are not
    general (``Metric.general``, e.g. CarRacing's steering follow-through and track tiles)
    and that this task reports; every other task reports them as NaN, so its tables and
    console leave them out."""

    def __post_init__(self) -> None:
        if not self.name or not self.env.env_id:
            raise ValueError("a task needs a name and an env_id")
        if self.episodes < 1 or self.eps <= 0:
            raise ValueError(f"{self.name}: episodes must be >= 1 and eps > 0")
        low, high = self.action_bounds
        if len(low) != len(high) or not low:
            raise ValueError(f"{self.name}: action_bounds must be two equal, non-empty tuples")
        if not self.safety_dims:
            raise ValueError(f"{self.name}: a task needs at least one safety dimension")
        if self.safety_units and len(self.safety_units) != len(self.safety_dims):
            raise ValueError(f"{self.name}: safety_units must name one unit per safety dimension")
        if self.safer_actions is not None and (
            len(self.safer_actions) != len(low) or set(self.safer_actions) - {-1, 1}
        ):
            raise ValueError(f"{self.name}: safer_actions must be -1 or +1 per action component")
        if isinstance(self.validation_episodes, bool) or not (
            isinstance(self.validation_episodes, int) and self.validation_episodes >= 0
        ):
            raise ValueError(f"{self.name}: validation_episodes must be an integer >= 0")
        if not self.episode_name.strip():
            raise ValueError(f"{self.name}: episode_name must name an episode (e.g. 'track')")

    @property
    def expert_type(self) -> type:
        """The task's expert config type."""
        return type(self.expert)

    @property
    def episodes_name(self) -> str:
        """:attr:`episode_name`'s plural (``tracks``, ``patients``, ``episodes``)."""
        return f"{self.episode_name}s"


TaskDefaults = TaskSpec
"""The former name of :class:`TaskSpec`."""

TASKS: dict[Task, TaskSpec] = {}
"""Task name -> its spec, in registration order (CarRacing first). Add with
:func:`register_task`; ``tests/test_tasks.py`` walks every entry."""


def register_task(spec: TaskSpec) -> TaskSpec:
    """Add ``spec`` to :data:`TASKS` and register its gymnasium ids. Registering the same
    spec again does nothing; another spec under a taken name or env id is an error."""
    known = TASKS.get(spec.name)
    if known is not None:
        if known != spec:
            raise ValueError(f"task {spec.name!r} is registered already")
        return known
    taken = [t.name for t in TASKS.values() if t.env.env_id == spec.env.env_id]
    if taken:
        raise ValueError(f"env {spec.env.env_id!r} belongs to task {taken[0]!r} already")
    for entry in spec.gym_envs:
        entry.register()
    TASKS[spec.name] = spec
    task_defaults.cache_clear()
    task_of.cache_clear()
    return spec


def register_envs() -> None:
    """Register every task's gymnasium ids (idempotent; entry points stay lazy)."""
    for spec in TASKS.values():
        for entry in spec.gym_envs:
            entry.register()


def _load_plugins() -> None:
    """Load the task plug-ins: the :data:`ENTRY_POINTS` entries of the installed packages
    (a :class:`TaskSpec` is registered), then the modules named in ``$SAFE_BC_TASKS`` (each
    registers its tasks).

    Raises:
        TaskPluginError: one line naming the plug-in that cannot be loaded and its error.
    """
    from importlib.metadata import entry_points

    for entry in entry_points(group=ENTRY_POINTS):
        where = f"task plug-in {entry.name!r} ({entry.value}"
        if entry.dist is not None:
            where += f", entry point of {entry.dist.name}"
        try:
            loaded = entry.load()
        except Exception as e:
            raise TaskPluginError(f"{where}) cannot be loaded: {_one_line(e)}") from None
        if isinstance(loaded, TaskSpec):
            register_task(loaded)
    for module in filter(None, (m.strip() for m in os.environ.get(PLUGINS_VAR, "").split(","))):
        try:
            importlib.import_module(module)
        except Exception as e:
            raise TaskPluginError(
                f"task module {module!r} (${PLUGINS_VAR}) cannot be imported: {_one_line(e)}"
            ) from None


def _one_line(e: BaseException) -> str:
    return f"{type(e).__name__}: {' '.join(str(e).split())}"


@functools.cache
def task_defaults(task: Task, renderer: Renderer = DEFAULT_RENDERER) -> TaskSpec:
    """The spec of ``task`` (a key of :data:`TASKS`), its env drawn by ``renderer`` where the
    task has renderers."""
    if task not in TASKS:
        _load_plugins()
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}: choose {' or '.join(TASKS)}")
    spec = TASKS[task]
    renderer = canonical_renderer(renderer)
    if spec.has_renderer and spec.env.renderer != renderer:
        spec = replace(spec, env=replace(spec.env, renderer=renderer))
    return spec


def _find(env_id: str) -> Task | None:
    return next((t.name for t in TASKS.values() if t.env.env_id == env_id), None)


@functools.cache
def task_of(env_id: str) -> Task:
    """The task whose env is ``env_id`` (cached: the shield looks it up every step)."""
    found = _find(env_id)
    if found is None:
        _load_plugins()
        found = _find(env_id)
    if found is None:
        raise ValueError(f"no task uses env {env_id!r} (known: {', '.join(TASKS)})")
    return found


def spec_of_env(env: gym.Env) -> TaskSpec | None:
    """The registered task whose env ``env`` is, matched by its gymnasium id (the task's env
    id or one it registers, e.g. a CarRacing renderer's); ``None``: no task claims it."""
    gym_id = env.spec.id if env.spec is not None else None
    for spec in TASKS.values():
        if gym_id == spec.env.env_id or gym_id in {g.id for g in spec.gym_envs}:
            return spec
    return None


def spec_of(env_id: str) -> TaskSpec:
    """The registered spec of the task whose env is ``env_id``."""
    return TASKS[task_of(env_id)]


def spec_of_expert(kind: type | str) -> TaskSpec:
    """The task whose expert config type is ``kind`` (a type, or its name as
    ``dataset.json`` records it)."""
    for attempt in range(2):
        for spec in TASKS.values():
            if kind in (spec.expert_type, spec.expert_type.__name__):
                return spec
        if attempt == 0:
            _load_plugins()
    name = kind if isinstance(kind, str) else kind.__name__
    raise ValueError(f"unknown expert config type {name!r}")
