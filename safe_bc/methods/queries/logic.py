"""Which steps are queried or deferred, query budgets, and the selection of the aggregate data
(pure numpy: no I/O, no torch, no Ray)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from safe_bc.methods.queries.config import QueryMode
from safe_bc.selection import (
    AddedIn,
    CriticalZone,
    Selection,
    SelectionConfig,
    select_with_added,
)


def ask_expert(cost: np.ndarray, warmup: bool, zone: CriticalZone, mode: QueryMode) -> bool:
    """Whether the expert is asked in a state of costs ``cost (S,)``: never during warm-up
    (unscored frames); in ``"full"`` mode at every other state; in ``"critical"`` mode when the
    state is in ``zone`` (``c_s >= d_s - eps``, combined over ``s``: entering or beyond).

    >>> zone = CriticalZone((10.0,), eps=2.0)
    >>> [ask_expert(np.array([c]), False, zone, "critical") for c in (7.9, 8.0, 11.0)]
    [False, True, True]
    >>> ask_expert(np.array([0.0]), False, zone, "full")
    True
    >>> ask_expert(np.array([9.0]), True, zone, "full")
    False
    """
    if warmup:
        return False
    if mode == "full":
        return True
    return bool(zone.critical(np.asarray(cost, np.float64)[None])[0])


def query_mask(
    costs: np.ndarray, warmup: np.ndarray, zone: CriticalZone, mode: QueryMode
) -> np.ndarray:
    """:func:`ask_expert` of every step: ``(T, S), (T,) -> (T,) bool``.

    >>> zone = CriticalZone((10.0, 10.0), eps=1.0)
    >>> query_mask(np.array([[9.0, 0.0], [0.0, 8.0], [12.0, 0.0]]), np.array([False, False, True]),
    ...            zone, "critical").tolist()
    [True, False, False]
    """
    warmup = np.asarray(warmup, bool)
    if mode == "full":
        return ~warmup
    return zone.critical(np.asarray(costs, np.float64), valid=~warmup)


def budget_keep(counts: Sequence[int], budget: int | None) -> list[int]:
    """Queries kept per episode when a round may ask at most ``budget`` (``None``: all): the
    first ones in episode order.

    >>> budget_keep([3, 4, 2], 5), budget_keep([3, 4, 2], None)
    ([3, 2, 0], [3, 4, 2])
    """
    if budget is None:
        return [int(c) for c in counts]
    left, out = int(budget), []
    for c in counts:
        take = min(int(c), left)
        out.append(take)
        left -= take
    return out


def context_rows(queried_steps: np.ndarray, frame_stack: int) -> np.ndarray:
    """The steps a set of queried steps needs for their inputs: each queried step and the
    ``frame_stack - 1`` steps before it (clipped at 0), sorted and unique.

    >>> context_rows(np.array([5, 6, 10]), 3).tolist()
    [3, 4, 5, 6, 8, 9, 10]
    """
    steps = np.asarray(queried_steps, np.int64)
    if len(steps) == 0:
        return steps
    back = np.arange(frame_stack, dtype=np.int64)
    return np.unique(np.maximum(steps[:, None] - back[None, :], 0))


def aggregate_selection(
    costs: np.ndarray,
    valid: np.ndarray,
    queried: np.ndarray,
    config: SelectionConfig,
    limits: np.ndarray,
    mode: QueryMode,
) -> Selection:
    """``T_eps`` of demonstrations plus queried states under the demonstrations' limits.

    ``d_s`` stays the demonstrations' (``limits``): a queried state beyond it must not widen
    the limit. A row is critical by the selection's rule (``c_s >= d_s - eps`` on valid rows);
    in ``"critical"`` mode every queried row also joins ``T_eps`` (it was asked because it is
    in the query zone, which may be wider than the selection's), so it carries the weight
    ``alpha`` of the critical part of every batch. In ``"full"`` mode (DAgger) queried rows are
    ordinary data: critical only by the rule. Only the alpha mix (``mode="mix"``) aggregates.

    >>> cfg = SelectionConfig(eps=1.0, alpha=0.5)
    >>> costs = np.array([[0.0], [9.5], [3.0], [3.0]])
    >>> valid, queried = np.array([True, True, True, False]), np.array([False, False, True, False])
    >>> aggregate_selection(costs, valid, queried, cfg, np.array([10.0]), "critical").mask.tolist()
    [False, True, True, False]
    >>> aggregate_selection(costs, valid, queried, cfg, np.array([10.0]), "full").mask.tolist()
    [False, True, False, False]
    """
    if config.mode != "mix":
        raise ValueError(f"queries aggregate into the alpha mix only, not mode={config.mode!r}")
    added_in: AddedIn = "critical" if mode == "critical" else "zone"  # "full": ordinary data
    return select_with_added(costs, valid, queried, config, limits, added_in, "a queried")


def deferred_steps(
    costs: np.ndarray, warmup: np.ndarray, limits: np.ndarray, width: float, combine: str = "any"
) -> np.ndarray:
    """Where a deferring policy hands over to the expert: ``c_s >= d_s - width`` (combined),
    outside warm-up: ``(T,) bool``. The same rule as a ``"critical"`` query with eps =
    ``width``.

    >>> deferred_steps(np.array([[7.0], [8.0], [9.0]]), np.array([False, False, True]),
    ...                np.array([10.0]), 2.0).tolist()
    [False, True, False]
    """
    zone = CriticalZone(tuple(np.ravel(limits)), float(width), combine)  # type: ignore[arg-type]
    return query_mask(costs, warmup, zone, "critical")


def smallest_safe_width(crossings: dict[float, int]) -> float | None:
    """The deferral width to use: the smallest measured width with no episode beyond ``d_s``
    (``None``: none reached zero; measure wider ones).

    >>> smallest_safe_width({0.0: 3, 1.0: 0, 2.0: 1, 4.0: 0})
    1.0
    >>> smallest_safe_width({1.0: 2}) is None
    True
    """
    zero = sorted(w for w, k in crossings.items() if k == 0)
    return zero[0] if zero else None
