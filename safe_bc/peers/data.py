"""A safe_bc demonstration set as DSRL's dataset dict, for OSRL's learners in their own env.

The mapping is the Minari export's (:func:`safe_bc.export.minari_export.episode_buffer_fields`
and :func:`~safe_bc.export.minari_export.dsrl_dataset`), without writing a Minari dataset:
one row per transition, ``costs`` the scalar of the state the action led to (by default the
critical-zone indicator, ``c_s >= d_s - eps`` in some dimension), an episode's last transition
reading its repeated last stored step. The actions are mapped to [-1, 1] from the dataset's
action bounds (OSRL's actors act in ``[-max_action, max_action]``; :func:`to_unit` /
:func:`from_unit`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from safe_bc.data.store import DatasetError, completed_episodes, episode_path, read_episode
from safe_bc.data.store import read_meta as read_dataset_meta
from safe_bc.export.limits import COSTS, DEFAULT_COST_RULE, CostRule, dataset_zone
from safe_bc.export.minari_export import DSRL_KEYS, episode_buffer_fields


def to_unit(actions: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """Actions in ``[low, high]`` mapped to [-1, 1] per dimension.

    >>> to_unit(np.array([[0.0, 5.0]]), np.array([0.0, 0.0]), np.array([1.0, 10.0])).tolist()
    [[-1.0, 0.0]]
    """
    low, high = np.asarray(low, np.float64), np.asarray(high, np.float64)
    return (2.0 * (np.asarray(actions, np.float64) - low) / (high - low) - 1.0).astype(np.float32)


def from_unit(actions: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """The inverse of :func:`to_unit`, clipped to ``[low, high]``.

    >>> from_unit(np.array([-1.0, 0.0, 2.0]), np.zeros(3), np.full(3, 10.0)).tolist()
    [0.0, 5.0, 10.0]
    """
    low, high = np.asarray(low, np.float64), np.asarray(high, np.float64)
    out = low + (np.asarray(actions, np.float64) + 1.0) * 0.5 * (high - low)
    return np.clip(out, low, high).astype(np.float32)


def episode_rows(fields: dict[str, Any]) -> dict[str, np.ndarray]:
    """One episode's Minari buffer fields (:func:`episode_buffer_fields`) as DSRL's rows, as
    :func:`~safe_bc.export.minari_export.dsrl_dataset` reads an export back."""
    obs = np.asarray(fields["observations"], np.float32)
    return {
        "observations": obs[:-1],
        "next_observations": obs[1:],
        "actions": np.asarray(fields["actions"], np.float32),
        "rewards": np.asarray(fields["rewards"], np.float32),
        "costs": np.asarray(fields["infos"][COSTS], np.float32)[1:],
        "terminals": np.asarray(fields["terminations"], bool),
        "timeouts": np.asarray(fields["truncations"], bool),
    }


def dsrl_from_demos(
    demos: str | Path, *, eps: float | None = None, cost: CostRule = DEFAULT_COST_RULE
) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """The demonstrations at ``demos`` as DSRL's dataset dict (:data:`DSRL_KEYS`; actions in
    [-1, 1]) and what it was made from: ``d_s`` per dimension, ``eps``, the cost rule, the
    action bounds, the observation and action sizes, the longest episode, the episodes' costs
    and the number of cost transitions.

    Raises:
        DatasetError: not a dataset, no episodes, or observations that are not vectors (OSRL's
            networks are MLPs: frames would need an encoder first).
    """
    root = Path(demos)
    meta = read_dataset_meta(root)
    if meta.obs_encoding != "vector" or len(meta.obs_shape) != 1:
        raise DatasetError(
            f"{root}: OSRL's learners take vector observations (MLPs); {meta.env_id} stores "
            f"{meta.obs_encoding} observations of shape {tuple(meta.obs_shape)} (frames would "
            "need a frozen encoder turning them into features first)"
        )
    ids = completed_episodes(root, meta)
    if not ids:
        raise DatasetError(f"{root}: dataset has no episodes; run `safe-bc collect`")
    from safe_bc.tasks import dataset_action_bounds

    zone = dataset_zone(root, meta, eps)
    low, high = (np.asarray(b, np.float64) for b in dataset_action_bounds(root))
    parts: dict[str, list[np.ndarray]] = {k: [] for k in DSRL_KEYS}
    episode_costs, lengths = [], []
    for i in ids:
        rows = episode_rows(episode_buffer_fields(read_episode(episode_path(root, i), meta),
                                                  zone, cost))  # fmt: skip
        rows["actions"] = to_unit(rows["actions"], low, high)
        for k in DSRL_KEYS:
            parts[k].append(rows[k])
        episode_costs.append(float(rows["costs"].sum()))
        lengths.append(len(rows["actions"]))
    data = {k: np.concatenate(v) for k, v in parts.items()}
    info = {
        "env_id": meta.env_id,
        "safety_dims": list(meta.safety_dims),
        "cost_limits": [float(x) for x in zone.limits],
        "eps": float(zone.eps),
        "cost_rule": cost,
        "action_low": low.tolist(),
        "action_high": high.tolist(),
        "state_dim": int(meta.obs_shape[0]),
        "action_dim": int(data["actions"].shape[1]),
        "episodes": len(ids),
        "transitions": len(data["actions"]),
        "episode_len": max(lengths),
        "episode_costs": episode_costs,
        "cost_transitions": int(data["costs"].sum()),
    }
    return data, info


def kept_by_budget(episode_costs: list[float], budget: float) -> int:
    """How many episodes have a cost within ``budget`` (the episodes OSRL's BC-Safe keeps).

    >>> kept_by_budget([0.0, 0.0, 1.0, 3.0], 1)
    3
    """
    return int(sum(c <= budget for c in episode_costs))


__all__ = ["dsrl_from_demos", "episode_rows", "from_unit", "kept_by_budget", "to_unit"]
