"""What the query and self-imitation rounds share: spreading a round's rollouts over workers
with the parallel factory the caller hands in."""

from __future__ import annotations

import pytest

from safe_bc.methods.rounds import spread


def _double(job: int, seeds: list[int]) -> list[int]:
    return [job * s for s in seeds]


def test_spread_uses_the_callers_parallel_factory() -> None:
    made = []

    def parallel(rollouts, workers):
        made.append((rollouts, workers))
        return lambda job, seeds: rollouts(job, list(reversed(seeds)))[::-1]

    rollouts = spread(_double, 3, parallel)
    assert made == [(_double, 3)]
    assert rollouts(2, [1, 2, 3]) == _double(2, [1, 2, 3])


def test_spread_without_a_factory_says_what_to_pass() -> None:
    with pytest.raises(ValueError, match=r"workers=2 needs a parallel rollout factory.*workers=0"):
        spread(_double, 2, None)
