"""In-memory demonstrations: the flat arrays that selection and training consume."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from safe_bc.data.episode import Episode


@dataclass(frozen=True)
class Demonstrations:
    """``N`` state-action pairs from one or more episodes, in episode/step order.

    Attributes:
        observations: ``(N, *obs_shape)``: ``(N, 96, 96, 3) uint8`` frames or ``(N, D) float32``;
            frames may be a ``safe_bc.data.frames.FrameFile`` (read from disk per index, the
            same arrays: ``load_demonstrations``'s ``stream`` mode).
        actions: ``(N, A) float32``, the expert's chosen actions (the BC labels).
        costs: ``(N, S) float32``, safety costs (higher is less safe).
        safety: ``(N, S) float32``, safety distances (higher is safer).
        episode_ids: ``(N,) int64``.
        steps: ``(N,) int64``, step index within the episode.
        seeds: ``(N,) int64``, the env seed of the step's episode.
        warmup: ``(N,) bool``, unscored steps (CarRacing zoom-in); selection ignores them.
        safety_dims: names of the ``S`` safety dimensions.
    """

    observations: np.ndarray
    actions: np.ndarray
    costs: np.ndarray
    safety: np.ndarray
    episode_ids: np.ndarray
    steps: np.ndarray
    seeds: np.ndarray
    warmup: np.ndarray
    safety_dims: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.actions)

    @property
    def scored(self) -> np.ndarray:
        """``(N,) bool``: steps that count for thresholds and training (not warm-up)."""
        return ~self.warmup

    @property
    def limits(self) -> np.ndarray:
        """``(S,) float64``: the expert's worst cost per dimension over the scored steps,
        ``d_s = max c_s``: the limit a policy must never go beyond (a violation)."""
        from safe_bc.selection import thresholds

        return thresholds(self.costs, "max", valid=self.scored)

    @property
    def safety_mean(self) -> float:
        """The demonstrations' safety mean: mean over the scored steps of the smallest
        distance (the expert's reference for the safety constraint)."""
        return float(np.min(self.safety[self.scored], axis=1).mean())

    def dim_safety_means(self) -> dict[str, float]:
        """Per-dimension safety means over the scored steps."""
        s = self.safety[self.scored]
        return {d: float(s[:, j].mean()) for j, d in enumerate(self.safety_dims)}

    def take(self, rows: np.ndarray) -> Demonstrations:
        """The demonstrations of ``rows (M,)`` (indices, in order)."""
        rows = np.asarray(rows, np.int64)
        return Demonstrations(
            observations=self.observations[rows],
            actions=self.actions[rows],
            costs=self.costs[rows],
            safety=self.safety[rows],
            episode_ids=self.episode_ids[rows],
            steps=self.steps[rows],
            seeds=self.seeds[rows],
            warmup=self.warmup[rows],
            safety_dims=self.safety_dims,
        )

    @classmethod
    def from_episodes(cls, episodes: Sequence[Episode], observations: Any = None) -> Demonstrations:
        """Concatenate episodes (in the given order) into flat arrays.

        ``observations``: the episodes' concatenated observations held elsewhere (a
        ``safe_bc.data.frames.FrameFile``, one row per step), used instead of theirs.

        >>> import numpy as np
        >>> from safe_bc.data.episode import Episode
        >>> T = 4
        >>> ep = Episode(0, 7, np.zeros((T, 2), np.float32), np.zeros((T, 3), np.float32),
        ...     np.zeros((T, 3), np.float32), np.zeros(T, np.float32), np.zeros(T, bool),
        ...     np.zeros(T, bool), np.ones((T, 3), np.float32), np.zeros((T, 3), np.float32),
        ...     np.zeros(T, bool), np.zeros(T, bool))
        >>> demos = Demonstrations.from_episodes([ep, ep])
        >>> len(demos), demos.seeds.tolist()
        (8, [7, 7, 7, 7, 7, 7, 7, 7])
        """
        if not episodes:
            raise ValueError("no episodes: the demonstration set is empty")
        dims = episodes[0].safety_dims
        if any(e.safety_dims != dims for e in episodes):
            raise ValueError("episodes disagree on safety dimensions")
        if observations is None:
            observations = np.concatenate([e.observations for e in episodes])
        elif len(observations) != sum(len(e) for e in episodes):
            raise ValueError(
                f"{len(observations)} observations for {sum(len(e) for e in episodes)} steps"
            )
        return cls(
            observations=observations,
            actions=np.concatenate([e.actions for e in episodes]).astype(np.float32),
            costs=np.concatenate([e.costs for e in episodes]).astype(np.float32),
            safety=np.concatenate([e.safety for e in episodes]).astype(np.float32),
            episode_ids=np.concatenate([np.full(len(e), e.episode_id, np.int64) for e in episodes]),
            steps=np.concatenate([np.arange(len(e), dtype=np.int64) for e in episodes]),
            seeds=np.concatenate([np.full(len(e), e.seed, np.int64) for e in episodes]),
            warmup=np.concatenate([e.warmup for e in episodes]).astype(bool),
            safety_dims=dims,
        )


def hold_out_episodes(
    demos: Demonstrations, episodes: int
) -> tuple[Demonstrations, Demonstrations]:
    """``(training, held out)``: the ``episodes`` episodes of ``demos`` with the highest ids held
    out (a fixed split: the same data give the same one), the others kept in their order.
    Raises ``ValueError`` unless at least one episode stays for training.

    >>> import numpy as np
    >>> ids = np.array([0, 0, 1, 2, 2])
    >>> d = Demonstrations(np.zeros((5, 2)), np.zeros((5, 1)), np.zeros((5, 1)),
    ...     np.zeros((5, 1)), ids, np.zeros(5, np.int64), np.zeros(5, np.int64),
    ...     np.zeros(5, bool), ("x",))
    >>> train, held = hold_out_episodes(d, 1)
    >>> train.episode_ids.tolist(), held.episode_ids.tolist()
    ([0, 0, 1], [2, 2])
    """
    ids = np.unique(demos.episode_ids)
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise ValueError(f"episodes to hold out must be an integer >= 1, got {episodes!r}")
    if episodes >= len(ids):
        raise ValueError(
            f"cannot hold out {episodes} of {len(ids)} demonstration episodes: at least one "
            "must stay for training"
        )
    held = np.isin(demos.episode_ids, ids[-episodes:])
    return demos.take(np.flatnonzero(~held)), demos.take(np.flatnonzero(held))
