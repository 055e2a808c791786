"""Round files (``queries.npz``, written atomically; numpy only, no torch). The training data
(demonstrations plus every queried episode's rows) is
:func:`safe_bc.methods.rounds.aggregate_rows`'s."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from safe_bc.data.atomic import atomic_write
from safe_bc.methods.queries.rollout import EpisodeQueries

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
