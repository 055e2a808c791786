"""Pushes, which pushed steps are kept, the training selection, the keep rule and the names of
results shared between runs (pure numpy: no I/O, no torch, no Ray)."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from safe_bc.methods.selfimprove.config import KeepUnit, KeptIn
from safe_bc.metrics import clopper_pearson_upper
from safe_bc.selection import Selection, SelectionConfig, select_with_added

Terms = Sequence[tuple[int, str, float]]


def push_action(action: np.ndarray, terms: Terms, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """The executed action of a push (:func:`~safe_bc.methods.selfimprove.config.parse_push` terms),
    clipped to ``[low, high]``.

    >>> push_action(np.array([0.0, 0.98, 0.5]), [(1, "+", 0.05), (2, "*", 0.5)],
    ...             np.array([-1.0, 0, 0]), np.ones(3)).tolist()
    [0.0, 1.0, 0.25]
    """
    out = np.array(action, np.float64, copy=True)
    for dim, op, value in terms:
        out[dim] = out[dim] * value if op == "*" else out[dim] + value
    return np.clip(out, low, high).astype(np.float32)


def safe_states(
    costs: np.ndarray,
    scored: np.ndarray,
    final_cost: np.ndarray | None,
    limits: np.ndarray,
    margin: float,
) -> np.ndarray:
    """``(T + 1,) bool``: each state of an episode (its ``T`` visited states, then the last
    step's outcome ``final_cost``) is inside ``d_s - margin`` in every dimension
    (``c_s <= d_s - margin``); unscored states (warm-up) count as inside. The outcome is
    scored when the last step is; without ``final_cost`` it counts as inside.

    >>> safe_states(np.array([[1.0], [3.0], [2.0]]), np.array([True, True, False]),
    ...             np.array([2.5]), np.array([3.0]), 0.5).tolist()
    [True, False, True, True]
    """
    costs = np.asarray(costs, np.float64)
    scored = np.asarray(scored, bool)
    bound = np.asarray(limits, np.float64) - float(margin)
    inside = np.all(costs <= bound, axis=1) | ~scored
    last = True
    if final_cost is not None and len(scored) and scored[-1]:
        last = bool(np.all(np.asarray(final_cost, np.float64) <= bound))
    return np.r_[inside, last]


def safe_steps(states: np.ndarray) -> np.ndarray:
    """``(T,) bool`` from :func:`safe_states`: step ``t`` starts and ends inside.

    >>> safe_steps(np.array([True, True, False, True])).tolist()
    [True, False, False]
    """
    states = np.asarray(states, bool)
    return states[:-1] & states[1:]


def window_sums(values: np.ndarray, length: int, n: int) -> np.ndarray:
    """Sums of ``values`` over the windows ``[k * length, (k + 1) * length)`` covering
    ``n`` steps (missing values count 0).

    >>> window_sums(np.array([1.0, 2, 3, 4, 5]), 2, 6).tolist()
    [3.0, 7.0, 5.0]
    """
    padded = np.zeros(-(-n // length) * length, np.float64)
    m = min(n, len(values))
    padded[:m] = np.asarray(values, np.float64)[:m]
    return padded.reshape(-1, length).sum(axis=1)


def kept_steps(
    unit: KeepUnit,
    costs: np.ndarray,
    scored: np.ndarray,
    final_cost: np.ndarray | None,
    rewards: np.ndarray,
    reference_rewards: np.ndarray,
    limits: np.ndarray,
    margin: float,
    segment_steps: int = 50,
) -> np.ndarray:
    """``(T,) bool``: the steps of a pushed episode that are kept.

    ``"episode"``: every step when every step stays inside ``d_s - margin``
    (:func:`safe_steps`) and the episode's reward beats the reference (the unperturbed run on
    the same track: ``reference_rewards``, its per-step rewards), else none. ``"segment"``:
    the steps of each window of ``segment_steps`` steps (from step 0) whose steps all stay
    inside and whose reward beats the reference's over the same steps (strictly).

    >>> costs, scored = np.array([[0.0], [0.0], [5.0], [0.0]]), np.ones(4, bool)
    >>> limits = np.array([3.0])
    >>> ones, zeros = np.ones(4), np.zeros(4)
    >>> bool(kept_steps("episode", costs, scored, None, ones, zeros, limits, 0.0).any())
    False
    >>> kept_steps("segment", costs, scored, None, np.ones(4), np.zeros(4), np.array([3.0]), 0.0,
    ...            segment_steps=2).tolist()
    [False, False, False, False]
    >>> kept_steps("segment", costs, scored, np.array([0.0]), np.ones(4), np.zeros(4),
    ...            np.array([6.0]), 0.5, segment_steps=2).tolist()
    [True, True, True, True]
    """
    rewards = np.asarray(rewards, np.float64)
    n = len(rewards)
    ok = safe_steps(safe_states(costs, scored, final_cost, limits, margin))
    if unit == "episode":
        keep = bool(ok.all()) and rewards.sum() > np.asarray(reference_rewards, np.float64).sum()
        return np.full(n, keep)
    if unit != "segment":
        raise ValueError(f"unit must be 'episode' or 'segment', got {unit!r}")
    windows = -(-n // segment_steps)
    better = window_sums(rewards, segment_steps, n) > window_sums(
        reference_rewards, segment_steps, n
    )
    inside = np.ones(windows * segment_steps, bool)
    inside[:n] = ok
    whole = inside.reshape(windows, segment_steps).all(axis=1)
    return np.repeat(better & whole, segment_steps)[:n]


def best_runs(kept: Sequence[bool], rewards: Sequence[float], k: int | None) -> np.ndarray:
    """``(P,) bool``: which pushed runs of a track stay kept when at most ``k`` may
    (``None``: all): among the runs with kept steps (``kept``), the ``k`` highest
    ``rewards`` (ties: the earlier push).

    >>> best_runs([True, False, True, True], [5.0, 9.0, 7.0, 7.0], 2).tolist()
    [False, False, True, True]
    >>> best_runs([True, True], [1.0, 2.0], None).tolist()
    [True, True]
    """
    kept = np.asarray(kept, bool)
    if k is None:
        return kept.copy()
    order = sorted(np.flatnonzero(kept), key=lambda i: (-float(rewards[i]), int(i)))
    out = np.zeros(len(kept), bool)
    out[order[: int(k)]] = True
    return out


def push_allowed(cost: np.ndarray, limits: np.ndarray, eps: float | None) -> bool:
    """Whether a push may act in a state of costs ``cost``: never in the back-off zone
    ``c_s >= d_s - eps`` (any dimension); ``eps=None``: always.

    >>> [push_allowed(np.array([c]), np.array([10.0]), 2.0) for c in (7.9, 8.0)]
    [True, False]
    >>> push_allowed(np.array([11.0]), np.array([10.0]), None)
    True
    """
    if eps is None:
        return True
    return not bool(np.any(np.asarray(cost, np.float64) >= np.asarray(limits, np.float64) - eps))


def kept_selection(
    costs: np.ndarray,
    valid: np.ndarray,
    kept: np.ndarray,
    config: SelectionConfig,
    limits: np.ndarray,
    kept_in: KeptIn,
) -> Selection:
    """The alpha mix over demonstrations plus kept rows (``kept (N,) bool``) under the
    demonstrations' limits ``d_s`` (a kept row never widens them). ``T_eps`` is the rule's
    (``c_s >= d_s - eps`` on valid rows) with the kept rows: taken out (``"rest"``: they
    join only the rest pool), as the rule says (``"zone"``) or all in (``"critical"``).

    >>> cfg = SelectionConfig(eps=1.0, alpha=0.5)
    >>> costs, valid = np.array([[9.5], [9.5], [0.0]]), np.ones(3, bool)
    >>> kept = np.array([False, True, True])
    >>> [kept_selection(costs, valid, kept, cfg, np.array([10.0]), k).mask.tolist()
    ...  for k in ("rest", "zone", "critical")]
    [[True, False, False], [True, True, False], [True, True, True]]
    """
    if config.mode != "mix":
        raise ValueError(f"self-imitation trains the alpha mix only, not mode={config.mode!r}")
    return select_with_added(costs, valid, kept, config, limits, kept_in, "a kept")


def accept_round(
    beyond: int,
    episodes: int,
    reward: float,
    previous_reward: float,
    limit: float,
    confidence: float = 0.95,
) -> tuple[bool, float]:
    """The keep rule: ``(accepted, bound)``. A round's agent is accepted when the one-sided
    Clopper-Pearson upper bound on its share of validation episodes beyond ``d_s``
    (``beyond`` of ``episodes``) is below ``limit`` and its mean validation ``reward`` is
    not below the previous (kept) agent's.

    >>> accept_round(0, 32, 5.0, 5.0, 0.1)[0], accept_round(1, 32, 6.0, 5.0, 0.1)[0]
    (True, False)
    >>> accept_round(0, 32, 4.9, 5.0, 0.1)[0]
    False
    """
    bound = clopper_pearson_upper(int(beyond), int(episodes), confidence)
    return bool(bound < limit and reward >= previous_reward), bound


def content_key(ingredients: Mapping[str, Any]) -> str:
    """SHA-256 of everything that made a result (a JSON-able mapping: its canonical JSON,
    keys sorted): the name of a result shared between runs (``<runs folder>/_shared/``).

    >>> content_key({"b": [1, 2.5], "a": "x"}) == content_key({"a": "x", "b": [1, 2.5]})
    True
    >>> content_key({"a": 1}) == content_key({"a": 1.0}), len(content_key({}))
    (False, 64)
    """
    text = json.dumps(ingredients, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()
