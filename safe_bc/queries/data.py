"""Round files (``queries.npz``, written atomically) and the aggregate training data:
demonstrations plus every queried state so far (numpy only, no torch)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from safe_bc.atomic import atomic_write
from safe_bc.demos import Demonstrations
from safe_bc.queries.rollout import EpisodeQueries

_ROW_FIELDS = ("steps", "queried", "observations", "actions", "costs")


def save_round(path: Path, episodes: Sequence[EpisodeQueries]) -> None:
    """One round's episodes to ``path`` (``.npz``), atomically: a killed write leaves none."""
    arrays: dict[str, np.ndarray] = {
        "n_rows": np.asarray([len(e.steps) for e in episodes], np.int64),
        "reward": np.asarray([e.reward for e in episodes], np.float64),
    }
    for name in ("seed", "length", "beyond_steps", "frame_stack"):
        arrays[name] = np.asarray([getattr(e, name) for e in episodes], np.int64)
    for name in _ROW_FIELDS:
        arrays[name] = np.concatenate([getattr(e, name) for e in episodes])
    with atomic_write(path) as f:
        np.savez(f, **arrays)


def load_round(path: Path) -> list[EpisodeQueries]:
    """The episodes :func:`save_round` wrote."""
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    bounds = np.r_[0, np.cumsum(arrays["n_rows"])]
    out = []
    for i in range(len(arrays["n_rows"])):
        rows = slice(int(bounds[i]), int(bounds[i + 1]))
        out.append(
            EpisodeQueries(
                seed=int(arrays["seed"][i]),
                length=int(arrays["length"][i]),
                reward=float(arrays["reward"][i]),
                beyond_steps=int(arrays["beyond_steps"][i]),
                steps=arrays["steps"][rows],
                queried=arrays["queried"][rows].astype(bool),
                observations=arrays["observations"][rows],
                actions=arrays["actions"][rows],
                costs=arrays["costs"][rows],
                frame_stack=int(arrays["frame_stack"][i]),
            )
        )
    return out


def aggregate(
    demos: Demonstrations, episodes: Sequence[EpisodeQueries]
) -> tuple[Demonstrations, np.ndarray]:
    """Demonstrations followed by the queried episodes' rows, and ``(N,) bool`` queried.

    Each queried episode gets its own episode id after the demonstrations'; its context rows
    (frames only stacked, never trained on) are marked as warm-up, i.e. not scored. Queried
    rows have no safety distances (``NaN``; training does not read them).
    """
    parts = [e for e in episodes if len(e.steps)]
    if not parts:
        return demos, np.zeros(len(demos), bool)
    first_id = int(demos.episode_ids.max()) + 1 if len(demos) else 0
    n_new = sum(len(e.steps) for e in parts)
    s = demos.costs.shape[1]
    agg = Demonstrations(
        observations=np.concatenate([demos.observations, *[e.observations for e in parts]]),
        actions=np.concatenate([demos.actions, *[e.actions for e in parts]]).astype(np.float32),
        costs=np.concatenate([demos.costs, *[e.costs for e in parts]]).astype(np.float32),
        safety=np.concatenate([demos.safety, np.full((n_new, s), np.nan, np.float32)]),
        episode_ids=np.concatenate(
            [
                demos.episode_ids,
                *[np.full(len(e.steps), first_id + i, np.int64) for i, e in enumerate(parts)],
            ]
        ),
        steps=np.concatenate([demos.steps, *[e.steps.astype(np.int64) for e in parts]]),
        seeds=np.concatenate(
            [demos.seeds, *[np.full(len(e.steps), e.seed, np.int64) for e in parts]]
        ),
        warmup=np.concatenate([demos.warmup, *[~e.queried for e in parts]]),
        safety_dims=demos.safety_dims,
    )
    queried = np.concatenate([np.zeros(len(demos), bool), *[e.queried for e in parts]])
    return agg, queried
