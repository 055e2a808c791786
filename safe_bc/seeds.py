"""Seed bookkeeping: which tracks (patients) train and which are held out.

Demonstration episodes and evaluation episodes draw environment seeds from two
disjoint ranges, so an evaluation never replays a track the expert demonstrated.
"""

from __future__ import annotations

import numpy as np

SEEDS_PER_RUN = 100_000
"""Width of the seed block owned by one ``--seed`` value."""
HELDOUT_OFFSET = 1 << 30
"""Evaluation seeds live at and above this value; demonstration seeds below it."""
VALIDATION_SEED = 10_000
"""Collection seed of a study's validation set (the episodes its curves' validation loss is
computed on): demonstration tracks of their own, far from the small collection seeds training
sets use and below the evaluation seeds."""


def demo_seed(seed: int, episode_id: int) -> int:
    """Environment seed of demonstration episode ``episode_id`` of collection ``seed``.

    >>> demo_seed(0, 3), demo_seed(2, 0)
    (3, 200000)
    """
    _check(seed, episode_id)
    return seed * SEEDS_PER_RUN + episode_id


def heldout_seed(seed: int, episode: int) -> int:
    """Environment seed of held-out evaluation episode ``episode`` of evaluation ``seed``.

    >>> heldout_seed(0, 0) >= HELDOUT_OFFSET
    True
    """
    _check(seed, episode)
    return HELDOUT_OFFSET + seed * SEEDS_PER_RUN + episode


def heldout_seeds(seed: int, n: int) -> list[int]:
    """The first ``n`` held-out seeds of evaluation ``seed``."""
    return [heldout_seed(seed, k) for k in range(n)]


def episode_rng(seed: int, episode_id: int, stream: int = 0) -> np.random.Generator:
    """Independent generator for one episode's noise (expert style, perturbations).

    It depends only on ``(seed, episode_id, stream)``, never on which worker runs
    the episode, so parallel collection stays deterministic.
    """
    return np.random.default_rng([seed, episode_id, stream])


def _check(seed: int, index: int) -> None:
    if seed < 0:
        raise ValueError(f"seed must be >= 0, got {seed}")
    if not 0 <= index < SEEDS_PER_RUN:
        raise ValueError(f"episode index must be in [0, {SEEDS_PER_RUN}), got {index}")
    if seed * SEEDS_PER_RUN + index >= HELDOUT_OFFSET:
        raise ValueError(f"seed {seed} is too large: demonstration seeds must stay below 2**30")
