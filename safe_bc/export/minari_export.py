"""Export a safe_bc demonstration set as a `Minari <https://minari.farama.org>`_ dataset.

Minari is the Farama Foundation's format for offline-RL datasets, the one that
gymnasium users load with ``minari.load_dataset``. It is an optional extra
(``pip install -e '.[minari]'``); this module imports it only when called.

What goes where, per episode of ``T`` stored steps (one Minari episode per safe_bc
episode, in episode-id order):

* ``observations``: ``T + 1`` entries, ``(T+1, 96, 96, 3) uint8`` frames (stored
  losslessly: no JPEG) or ``(T+1, D) float32`` vectors. safe_bc stores the ``T``
  observations an action was chosen in, not the one after the last step, so **the final
  observation is a copy of the last stored one** and ``infos["repeated_observation"]``
  is ``True`` there (only there). Steps ``0..T-1`` are exactly the stored observations.
* ``actions``: ``(T, A) float32``, the expert's recorded action (the label; under a
  perturbation the executed action differs and is in ``infos["executed_action"]``).
* ``rewards``, ``terminations``, ``truncations``: ``(T,)``, as stored.
* ``infos`` (Minari's rule: the same keys at every entry, ``T + 1`` entries, entry ``i``
  describes ``observations[i]``, entry 0 being the reset's):

  - ``safety`` ``(T+1, S) float32`` distances, higher is safer (CarRacing: pixels to the
    grass left/front/right; rehab: margins to the limits);
  - ``cost`` ``(T+1, S) float32``, higher is less safe;
  - ``costs`` ``(T+1,)`` 0.0 or 1.0 (read back as float64), the scalar cost in DSRL's form
    (:func:`safe_bc.export.limits.step_costs`): by default 1.0 where ``observations[i]`` is
    a scored step in the critical zone (``c_s >= d_s - eps`` in some dimension), else 0.0;
    ``cost="beyond"``: 1.0 only beyond the limit (``c_s > d_s``);
  - ``warmup``, ``offroad`` ``(T+1,) bool``;
  - ``executed_action`` ``(T+1, A) float32``: entry ``t`` is the action sent to the env
    from ``observations[t]`` (aligned with ``actions[t]``; zeros at the final entry);
  - ``repeated_observation`` ``(T+1,) bool``: ``True`` at the final entry, whose
    observation, safety, cost, warmup and offroad repeat entry ``T - 1``.

Each episode's Minari metadata has the reset ``seed`` and ``safe_bc_episode_id``; the
dataset's metadata has ``safe_bc`` (the source ``dataset.json``), ``safe_bc_safety_dims``
and the limits ``costs`` was computed by (:func:`safe_bc.export.limits.limits_metadata`):
``safe_bc_cost_limits`` (``d_s`` per dimension), ``safe_bc_eps``, ``safe_bc_cost_rule``,
``safe_bc_cost_steps`` (how many steps the scalar marks) and ``safe_bc_critical_zone`` (the
rules). The env spec is the one :func:`safe_bc.tasks.make_env` builds (for CarRacing with the
safety wrapper), so ``dataset.recover_environment()`` gives an env whose ``info`` has the
same ``safety``/``cost`` keys. Minari stores the spec as JSON: an env registered with a
callable entry point (a plug-in task's ``GymEnv(id, Class)``) is stored by the callable's
import path, ``module:Class``, and refused in one line where it has none
(:func:`storable_spec`). :func:`dsrl_dataset` reads an export back as DSRL's dataset dict.

>>> import importlib.util
>>> importlib.util.find_spec("minari") is None or callable(export_minari)
True
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import shutil
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from safe_bc.data.episode import Episode
from safe_bc.data.store import (
    DatasetError,
    DatasetMeta,
    completed_episodes,
    episode_path,
    read_episode,
    read_meta,
)
from safe_bc.export.limits import (
    COSTS,
    DEFAULT_COST_RULE,
    CostRule,
    dataset_zone,
    limits_metadata,
    step_costs,
)
from safe_bc.selection import CriticalZone

INFO_KEYS: tuple[str, ...] = (
    "safety",
    "cost",
    COSTS,
    "warmup",
    "offroad",
    "executed_action",
    "repeated_observation",
)
"""The keys of every exported step's ``infos``."""

DATA_FORMAT = "arrow"
"""Minari storage backend: Arrow IPC (pyarrow is a safe_bc dependency; ``hdf5`` would need
h5py)."""


class MinariNotInstalledError(ImportError):
    """Minari is an optional extra that is not installed."""


def import_minari() -> Any:
    """``import minari``, or a one-line error saying how to install it."""
    try:
        import minari
    except ImportError:
        raise MinariNotInstalledError(
            "Minari export needs the optional extra: pip install -e '.[minari]' "
            "(or pip install minari)"
        ) from None
    return minari


def episode_buffer_fields(
    episode: Episode, zone: CriticalZone | None = None, cost: CostRule = DEFAULT_COST_RULE
) -> dict[str, Any]:
    """The Minari ``EpisodeBuffer`` fields of one safe_bc episode (see the module doc);
    ``zone`` (``d_s`` per dimension and eps) and ``cost`` (the rule) give the scalar
    ``costs`` (no zone: all 0.0).

    >>> from safe_bc.data.episode import Episode
    >>> n = 2
    >>> ep = Episode(0, 7, np.zeros((n, 4), np.float32), np.ones((n, 2), np.float32),
    ...              np.ones((n, 2), np.float32), np.zeros(n, np.float32), np.array([0, 1], bool),
    ...              np.zeros(n, bool), np.ones((n, 3), np.float32), np.zeros((n, 3), np.float32),
    ...              np.zeros(n, bool), np.zeros(n, bool))
    >>> f = episode_buffer_fields(ep, CriticalZone((1.0, 1.0, 1.0), eps=0.5))
    >>> f["observations"].shape, f["actions"].shape, f["infos"]["safety"].shape
    ((3, 4), (2, 2), (3, 3))
    >>> f["infos"]["repeated_observation"]
    [False, False, True]
    >>> f["infos"]["costs"]
    [0.0, 0.0, 0.0]
    """
    n = len(episode)

    def pad_repeat(a: np.ndarray) -> np.ndarray:
        return np.concatenate([a, a[-1:]], axis=0)

    executed = episode.executed_actions.astype(np.float32)
    if zone is None:
        scalar = np.zeros(n, np.float32)
    else:
        scalar = step_costs(episode.costs, episode.warmup, zone, cost)
    infos = {
        "safety": pad_repeat(episode.safety.astype(np.float32)),
        "cost": pad_repeat(episode.costs.astype(np.float32)),
        COSTS: pad_repeat(scalar),
        "warmup": pad_repeat(episode.warmup.astype(bool)),
        "offroad": pad_repeat(episode.offroad.astype(bool)),
        "executed_action": np.concatenate([executed, np.zeros_like(executed[:1])], axis=0),
        "repeated_observation": np.arange(n + 1) == n,
    }
    # Minari 0.5's Arrow storage cannot read back 1-D ndarray infos (it records an empty
    # shape); as lists of Python scalars they round-trip to the same 1-D numpy arrays.
    infos = {k: v.tolist() if v.ndim == 1 else v for k, v in infos.items()}
    return {
        "seed": int(episode.seed),
        "observations": pad_repeat(episode.observations),
        "actions": episode.actions.astype(np.float32),
        "rewards": episode.rewards.astype(np.float32),
        "terminations": episode.terminated.astype(bool),
        "truncations": episode.truncated.astype(bool),
        "infos": infos,
    }


def _episodes(root: Path, meta: DatasetMeta) -> Iterator[Episode]:
    """The stored episodes in id order, one at a time (a dataset need not fit in memory)."""
    for episode_id in completed_episodes(root, meta):
        yield read_episode(episode_path(root, episode_id), meta)


def _env_for(meta: DatasetMeta) -> Any:
    from safe_bc.tasks import make_env
    from safe_bc.tasks.env_config import EnvConfig

    return make_env(EnvConfig(env_id=meta.env_id, max_episode_steps=meta.max_steps))


def _description(meta: DatasetMeta, root: Path, cost: CostRule) -> str:
    marks = {
        "critical": "in the critical zone, c_s >= d_s - eps,",
        "beyond": "beyond the limit d_s",
    }[cost]
    return (
        f"safe_bc expert demonstrations of {meta.env_id} exported from {root}: actions are "
        "the expert's recorded actions; infos hold per-step safety distances ('safety', "
        f"dims {list(meta.safety_dims)}, higher is safer), costs ('cost'), 'warmup', "
        f"'offroad', 'executed_action' and DSRL's scalar 'costs' (1.0 at a scored step {marks} "
        "in some dimension; d_s, eps and the rule are in the dataset metadata, "
        "safe_bc_cost_limits, safe_bc_eps and safe_bc_cost_rule). safe_bc does not store the "
        "observation after the last step: each episode's final observation repeats the last "
        "stored one (infos['repeated_observation'] is True there)."
    )


def entry_point_path(entry: Any) -> str | None:
    """``module:name`` of a callable entry point that importing ``module`` and reading its
    top-level ``name`` gives back (gymnasium's form of an entry point); ``None`` where there is
    none (a lambda, a class defined in a function or in ``__main__``, a nested class)."""
    module, name = getattr(entry, "__module__", None), getattr(entry, "__qualname__", "")
    if not module or module == "__main__" or not name.isidentifier():
        return None
    try:
        found = getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError):
        return None
    return f"{module}:{name}" if found is entry else None


def storable_spec(env: Any) -> Any:
    """``env``'s spec as Minari can store it (as JSON): unchanged for an entry point given as
    ``module:Class``, else with the callable replaced by its import path
    (:func:`entry_point_path`).

    Raises:
        ValueError: one line naming the env and the fix, when the callable has no import
            path.
    """
    spec = env.spec
    if spec is None or isinstance(spec.entry_point, str):
        return spec
    path = entry_point_path(spec.entry_point)
    if path is None:
        raise ValueError(
            f"{spec.id}: its entry point {spec.entry_point!r} is a callable without an import "
            "path, which a Minari dataset cannot store; register the env by one, "
            f"GymEnv({spec.id!r}, 'module:Class'), or define the class at the top level of an "
            "importable module; nothing was written"
        )
    return dataclasses.replace(spec, entry_point=path)


def check_dataset_id(dataset_id: str) -> None:
    """``dataset_id`` must be a Minari id with a version, ``(namespace/)name-vN``.

    Raises:
        ValueError: one line naming the id and the form it must have.
    """
    from minari.dataset.minari_dataset import DATASET_ID_RE

    match = DATASET_ID_RE.fullmatch(dataset_id)
    if not match or match.group("version") is None:
        raise ValueError(
            f"--dataset-id {dataset_id!r} is not a Minari dataset id: it must be "
            "(namespace/)name-vN, e.g. safe_bc/carracing-drift-v0 (letters, digits, - and _); "
            "nothing was written"
        )


def export_minari(
    demos: str | Path,
    dataset_id: str,
    *,
    author: str | None = None,
    description: str | None = None,
    eps: float | None = None,
    cost: CostRule = DEFAULT_COST_RULE,
) -> Any:
    """Write the safe_bc dataset at ``demos`` as the Minari dataset ``dataset_id``.

    The dataset goes where Minari keeps local datasets: ``$MINARI_DATASETS_PATH`` if set,
    else Minari's default (``~/.minari/datasets``). Episodes are read and written one at a
    time. On any failure the partly written Minari dataset is removed.

    Args:
        demos: a directory written by ``safe-bc collect``.
        dataset_id: e.g. ``safe_bc/carracing-drift-v0`` (``namespace/name-vN``).
        author: optional author recorded in the Minari metadata.
        description: defaults to a summary of the layout (see the module doc).
        eps: the critical zone's width (cost units); ``None``: the task's.
        cost: which steps the scalar ``costs`` marks
            (:data:`safe_bc.export.limits.CostRule`): the critical zone (default) or the
            steps beyond ``d_s``.

    Returns:
        The ``minari.MinariDataset``.

    Raises:
        MinariNotInstalledError: the ``minari`` extra is missing.
        DatasetError: ``demos`` is not a readable safe_bc dataset, or has no episodes.
        ValueError: ``dataset_id`` is not a versioned Minari id (checked before anything is
            created), a Minari dataset ``dataset_id`` exists already, or the env's callable
            entry point has no import path (:func:`storable_spec`).
    """
    minari = import_minari()
    check_dataset_id(dataset_id)  # before Minari makes any folder
    from minari.storage import get_dataset_path

    root = Path(demos)
    meta = read_meta(root)
    if not completed_episodes(root, meta):
        raise DatasetError(f"{root}: dataset has no episodes; run `safe-bc collect`")
    target = Path(get_dataset_path(dataset_id))
    if target.exists():
        raise ValueError(
            f"Minari dataset {dataset_id} already exists at {target}; delete it "
            f"(minari delete {dataset_id}) or choose another --dataset-id"
        )
    zone = dataset_zone(root, meta, eps)
    env = _env_for(meta)
    try:
        spec = storable_spec(env)
        shape = tuple(int(x) for x in env.observation_space.shape)
        if shape != tuple(meta.obs_shape):
            raise DatasetError(
                f"{root}: observations of shape {tuple(meta.obs_shape)} do not fit "
                f"{meta.env_id}'s observation space {shape}"
            )
        source = env if spec is env.spec else spec
        text = description or _description(meta, root, cost)
        try:
            _write(minari, dataset_id, root, meta, source, author, text, zone, cost)
        except BaseException:
            shutil.rmtree(target, ignore_errors=True)
            raise
    finally:
        env.close()
    return minari.load_dataset(dataset_id)


def _write(
    minari: Any,
    dataset_id: str,
    root: Path,
    meta: DatasetMeta,
    env: Any,
    author: str | None,
    description: str,
    zone: CriticalZone,
    cost: CostRule,
) -> None:
    """The episodes at ``root`` written one at a time as the Minari dataset ``dataset_id``
    (``env``: the env, or its storable spec), then the dataset's metadata."""
    from minari.data_collector import EpisodeBuffer

    dataset = None
    ids: list[int] = []
    marked = 0
    for episode in _episodes(root, meta):
        fields = episode_buffer_fields(episode, zone, cost)
        marked += int(sum(fields["infos"][COSTS][:-1]))  # the stored steps, not the repeat
        buffer = EpisodeBuffer(**fields)
        if dataset is None:
            with warnings.catch_warnings():  # optional provenance fields
                warnings.filterwarnings(
                    "ignore", r"`(author|author_email|code_permalink)` is set to None"
                )
                dataset = minari.create_dataset_from_buffers(
                    dataset_id=dataset_id,
                    buffer=[buffer],
                    env=env,
                    eval_env=env,
                    algorithm_name=f"safe_bc expert ({meta.expert.get('type', 'expert')})",
                    author=author,
                    description=description,
                    data_format=DATA_FORMAT,
                    jpeg_encoding=False,
                )
        else:
            dataset.update_dataset_from_buffer([buffer])
        ids.append(episode.episode_id)
    assert dataset is not None  # at least one episode, checked by the caller
    dataset.storage.update_episode_metadata(
        [{"safe_bc_episode_id": i} for i in ids], range(len(ids))
    )
    dataset.storage.update_metadata(
        {
            "safe_bc": json.loads(meta.to_json()),
            "safe_bc_safety_dims": list(meta.safety_dims),
            **limits_metadata(zone, meta.safety_dims, cost),
            "safe_bc_cost_steps": marked,
        }
    )


DSRL_KEYS: tuple[str, ...] = (
    "observations",
    "actions",
    "rewards",
    "costs",
    "terminals",
    "timeouts",
    "next_observations",
)
"""The arrays of DSRL's dataset dict (``env.get_dataset()``), the one OSRL's learners read."""


def dsrl_dataset(dataset: Any) -> dict[str, np.ndarray]:
    """An exported Minari dataset as DSRL's dataset dict (:data:`DSRL_KEYS`), one row per
    transition over all episodes: the observation an action was chosen in and the next one,
    the action, reward, ``terminals`` (terminations) and ``timeouts`` (truncations), and
    ``costs``, the scalar of the state the action led to (``infos["costs"][1:]``; an
    episode's last transition reads the repeated last stored step)."""
    parts: dict[str, list[np.ndarray]] = {k: [] for k in DSRL_KEYS}
    for ep in dataset.iterate_episodes():
        obs = np.asarray(ep.observations)
        parts["observations"].append(obs[:-1])
        parts["next_observations"].append(obs[1:])
        parts["actions"].append(np.asarray(ep.actions))
        parts["rewards"].append(np.asarray(ep.rewards, np.float32))
        parts["costs"].append(np.asarray(ep.infos[COSTS], np.float32)[1:])
        parts["terminals"].append(np.asarray(ep.terminations, bool))
        parts["timeouts"].append(np.asarray(ep.truncations, bool))
    return {k: np.concatenate(v) for k, v in parts.items()}


__all__ = [
    "DATA_FORMAT",
    "DSRL_KEYS",
    "INFO_KEYS",
    "MinariNotInstalledError",
    "dsrl_dataset",
    "entry_point_path",
    "episode_buffer_fields",
    "export_minari",
    "import_minari",
    "storable_spec",
]
