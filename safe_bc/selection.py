"""Safety-critical state selection and the alpha-mixed batch sampler (paper sec. 3.2, eqs. 4-5).

Pure numpy: no I/O, no torch. Given per-step safety costs ``(N, S)`` (higher is less
safe) of the expert demonstrations ``T_exp``:

* ``d_s = max_t c_s(s_t)`` per safety dimension (or a high quantile, robust to one
  outlier), over scored rows only (warm-up rows are excluded);
* ``T_eps = {(s_t, a_t) : c_s(s_t) >= d_s - eps}`` per dimension, combined over the
  ``S`` dimensions with ``any`` (critical in some direction) or ``all``;
* every training batch holds exactly ``round(alpha * B)`` pairs drawn from ``T_eps``
  and the rest from ``T_exp`` (or ``T_exp \\ T_eps``, see ``SelectionConfig.rest``).

Two peer baselines are selection rules on the same ``d_s`` and ``T_eps`` (``SelectionConfig.mode``),
sampled by :class:`WeightedBatchSampler` instead of the alpha mix:

* ``"bc_safe"`` (OSRL's BC-Safe): train only on the demonstration *segments* (windows of
  ``segment_steps`` consecutive scored steps of one episode) that never enter ``T_eps``
  (:func:`segment_ids`, :func:`safe_segment_rows`);
* ``"cost_weighted"``: every scored row, drawn with a weight that grows with its cost
  (:func:`cost_weights`).

>>> costs = np.array([[0.0], [4.0], [9.0], [10.0]], np.float32)
>>> sel = select(costs, SelectionConfig(eps=2.0, alpha=0.5))
>>> sel.thresholds.tolist(), sel.mask.tolist()
([10.0], [False, False, True, True])
>>> sampler = MixedBatchSampler(sel.mask, 0.5, 4, "noncritical", np.random.default_rng(0))
>>> int(sel.mask[sampler.sample()].sum())
2
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any, Literal, Protocol, get_args

import numpy as np

ThresholdMode = Literal["max", "quantile"]
Combine = Literal["any", "all"]
Rest = Literal["all", "noncritical"]
Baseline = Literal["bc_safe", "cost_weighted"]
AddedIn = Literal["rest", "zone", "critical"]
"""The peer baselines: every rule of :data:`RULES` but the paper's mix."""
SelectionMode = Literal["mix", Baseline]


DEFAULT_EPS = 2.0
"""CarRacing's critical-zone width, 2 px (its ``TaskSpec.eps``; every task has its own, the
rehabilitation pathway's is 0.05). The one place this number is written."""


class SelectionError(ValueError):
    """The data cannot support the requested selection (no valid rows, empty pool, ...)."""


class CriticalSubsetWarning(UserWarning):
    """The alpha mix cannot focus: ``T_eps`` holds none or all of the scored rows, so eps does
    not fit the demonstrations' cost scale (:func:`warn_if_improper_subset`)."""


def _check_choice(name: str, value: object, options: tuple[str, ...]) -> None:
    if value not in options:
        raise ValueError(f"{name} must be one of {options}, got {value!r}")


@dataclass(frozen=True)
class SelectionConfig:
    """How to pick the safety-critical set ``T_eps`` and how to mix it into batches."""

    eps: float | None = None
    """Width of the critical edge, in the cost's units; ``None`` (default): the task's
    (``TaskSpec.eps``: 2 px for CarRacing, 0.05 for rehab). A row is critical in dimension
    ``s`` when ``c_s >= d_s - eps``; ``eps = 0`` keeps only the rows at the threshold itself.
    An unset width is set by :meth:`with_eps` where the task is known (a study, ``safe-bc
    train`` and :func:`safe_bc.cli.api.train`, a comparison: :func:`safe_bc.tasks.with_task_eps`);
    selecting with it unset is an error. CarRacing's 2 px puts ~9% of the default
    demonstrations in T_eps (the paper's 5 px was on another scale; here 5 px from the
    expert's closest approach reaches the road's centre)."""

    alpha: float = 0.5
    """Safety focus in ``[0, 1]``: the fraction of every batch drawn from ``T_eps``."""

    threshold: ThresholdMode = "max"
    """``"max"``: ``d_s`` is the largest cost seen (the paper); ``"quantile"``: the
    ``quantile``-th quantile, so a single outlier cannot set the threshold."""

    quantile: float = 0.99
    """Quantile in ``(0, 1]`` used when ``threshold == "quantile"`` (1.0 equals ``"max"``)."""

    combine: Combine = "any"
    """How per-dimension masks combine into ``T_eps``: ``"any"`` (critical in at least one
    dimension) or ``"all"`` (critical in every dimension)."""

    rest: Rest = "all"
    """Where the ``(1 - alpha)`` part of a batch comes from. Eq. 5 reads ``T_exp \\ T_eps``
    (``"noncritical"``), the text says "randomly sampled trajectories from T_exp" (``"all"``).

    Default ``"all"``: then ``alpha = 0`` is exactly plain, unweighted behaviour cloning (the
    paper's own reading of ``alpha = 0``, Table 1) rather than BC with the edge states removed,
    ``alpha = 1`` is BC on ``T_eps`` only, and any ``alpha`` in between is a mixture of these
    two well-defined baselines whose critical share is at least ``alpha``. With
    ``"noncritical"`` the critical share is exactly ``alpha``."""

    mode: SelectionMode = "mix"
    """The training rule, all on the same ``d_s`` and ``T_eps``:

    * ``"mix"``: the paper's alpha mix (``alpha``, ``rest``); ``alpha = 0`` with
      ``rest="all"`` is plain BC, ``alpha = 1`` is BC on ``T_eps`` only.
    * ``"bc_safe"``: OSRL's BC-Safe, BC on the demonstration segments that stay within a cost
      budget. The budget cannot be ``d_s`` itself (``d_s`` is the demonstrations' own worst
      cost, so every segment is within it); it is the critical edge: a segment is kept when
      none of its steps is in ``T_eps`` (``c_s < d_s - eps`` throughout, combined with
      ``combine``). Segments are windows of ``segment_steps`` consecutive scored steps of one
      episode; every kept row is drawn uniformly. Raises ``SelectionError`` when no segment
      survives.
    * ``"cost_weighted"``: BC on every scored row, drawn with probability proportional to
      ``w = 1 + beta * (1 - g / g_max)`` (see ``beta``): no hard subset.

    ``alpha`` and ``rest`` only apply to ``"mix"`` (the baselines ignore them, so a study may
    search ``mode`` beside ``alpha``)."""

    segment_steps: int = 20
    """BC-Safe's segment length K in scored steps (``mode="bc_safe"``): each episode's scored
    steps are cut, in order, into windows of K (the last one may be shorter), and a window is
    kept only if none of its steps is critical. K = 20 is 0.4 s of CarRacing driving; on the
    default demonstrations at eps = 2 px it keeps 158 of 210 segments (75% of the rows), while
    whole episodes (K >= the episode length, OSRL's trajectory-level filter) keep nothing,
    because every episode comes near an edge."""

    beta: float = 9.0
    """Cost-weighted BC's strength ``>= 0`` (``mode="cost_weighted"``): a row's weight is
    ``w = 1 + beta * (1 - g / g_max)``, where ``g = min_s (d_s - c_s)`` (``max_s`` with
    ``combine="all"``, clipped at 0) is its margin to the limit (``T_eps`` is ``{g <= eps}``), and
    ``g_max`` the largest margin over the scored rows. A row at the limit is drawn
    ``1 + beta`` times as often as the row furthest from every limit; ``beta = 0`` is plain BC.
    The margin is normalised once over the rows rather than per dimension
    (``(c_s - min c_s) / (d_s - min c_s)``) because the left and right distances add up to the
    road's width: every CarRacing row is at least half-way to the limit on one side, and the
    per-dimension form would weight all rows within a factor ~2 of each other. The default
    beta = 9 raises the expected critical share of a batch from 9% (plain BC) to 16% on the
    default demonstrations at eps = 2 px."""

    def __post_init__(self) -> None:
        if self.eps is not None and not (math.isfinite(self.eps) and self.eps >= 0):
            raise ValueError(f"eps must be a finite number >= 0, got eps={self.eps!r}")
        if not (0.0 <= self.alpha <= 1.0):
            raise ValueError(f"alpha must be in [0, 1], got alpha={self.alpha!r}")
        if not (0.0 < self.quantile <= 1.0):
            raise ValueError(f"quantile must be in (0, 1], got quantile={self.quantile!r}")
        _check_choice("threshold", self.threshold, get_args(ThresholdMode))
        _check_choice("combine", self.combine, get_args(Combine))
        _check_choice("rest", self.rest, get_args(Rest))
        _check_choice("mode", self.mode, get_args(SelectionMode))
        if (
            isinstance(self.segment_steps, bool)
            or not isinstance(self.segment_steps, int | np.integer)
            or self.segment_steps < 1
        ):
            raise ValueError(
                f"segment_steps must be an integer >= 1, got segment_steps={self.segment_steps!r}"
            )
        if not (math.isfinite(self.beta) and self.beta >= 0):
            raise ValueError(f"beta must be a finite number >= 0, got beta={self.beta!r}")

    def to_dict(self) -> dict[str, Any]:
        """JSON-able field dict."""
        return asdict(self)

    def with_eps(self, eps: float) -> SelectionConfig:
        """This config with ``eps`` as its width where it has none (a set width is kept)."""
        return self if self.eps is not None else replace(self, eps=float(eps))

    @property
    def width(self) -> float:
        """``eps``, which must be set.

        Raises:
            ValueError: ``eps`` is ``None`` (the task's width, not yet resolved).
        """
        if self.eps is None:
            raise ValueError(
                "SelectionConfig.eps is None (the task's critical-zone width) and no task "
                "resolved it: give eps, or resolve it with safe_bc.tasks.with_task_eps"
            )
        return self.eps


def _check_costs(costs: np.ndarray, valid: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Validate shapes; return ``(costs (N, S) float64, valid (N,) bool)``."""
    costs = np.asarray(costs)
    if costs.ndim != 2 or costs.shape[1] < 1:
        raise ValueError(f"costs must have shape (N, S) with S >= 1, got {costs.shape}")
    n = costs.shape[0]
    if valid is None:
        valid = np.ones(n, bool)
    else:
        valid = np.asarray(valid)
        if valid.shape != (n,) or valid.dtype != bool:
            raise ValueError(
                f"valid must be a ({n},) bool array, got shape {valid.shape} dtype {valid.dtype}"
            )
    return costs.astype(np.float64, copy=False), valid


def thresholds(
    costs: np.ndarray,
    mode: ThresholdMode = "max",
    quantile: float = 0.99,
    valid: np.ndarray | None = None,
) -> np.ndarray:
    """Per-dimension threshold ``d_s`` over the valid rows.

    Args:
        costs: ``(N, S)`` safety costs, higher is less safe.
        mode: ``"max"`` or ``"quantile"`` (linear interpolation, clipped to the max).
        quantile: in ``(0, 1]``, used when ``mode == "quantile"``.
        valid: ``(N,) bool`` rows to use (e.g. ``~warmup``); ``None`` uses all rows.

    Returns:
        ``(S,) float64``.

    Raises:
        SelectionError: no valid rows, or non-finite costs in valid rows.
    """
    _check_choice("mode", mode, get_args(ThresholdMode))
    if not (0.0 < quantile <= 1.0):
        raise ValueError(f"quantile must be in (0, 1], got quantile={quantile!r}")
    c, valid = _check_costs(costs, valid)
    rows = c[valid]
    if len(rows) == 0:
        raise SelectionError(f"no valid rows to compute thresholds from (N={len(c)})")
    bad = ~np.isfinite(rows)
    if bad.any():
        raise SelectionError(f"{int(bad.any(axis=1).sum())} valid rows have non-finite costs")
    top = rows.max(axis=0)
    if mode == "max":
        return top
    return np.minimum(np.quantile(rows, quantile, axis=0), top)


def critical_dims(
    costs: np.ndarray, d: np.ndarray, eps: float, valid: np.ndarray | None = None
) -> np.ndarray:
    """Per-dimension critical mask ``c_s >= d_s - eps`` (in float64); invalid rows never.

    Args:
        costs: ``(N, S)``.
        d: ``(S,)`` thresholds.
        eps: edge width, ``>= 0``.
        valid: ``(N,) bool`` or ``None`` (all valid).

    Returns:
        ``(N, S) bool``.
    """
    if not (math.isfinite(eps) and eps >= 0):
        raise ValueError(f"eps must be a finite number >= 0, got eps={eps!r}")
    c, valid = _check_costs(costs, valid)
    d = np.asarray(d, np.float64)
    if d.shape != (c.shape[1],):
        raise ValueError(f"thresholds must have shape ({c.shape[1]},), got {d.shape}")
    return (c >= d - eps) & valid[:, None]


def combine_dims(per_dim: np.ndarray, combine: Combine = "any") -> np.ndarray:
    """``(N, S) bool -> (N,) bool`` with ``any`` or ``all`` over the dimensions."""
    _check_choice("combine", combine, get_args(Combine))
    per_dim = np.asarray(per_dim, bool)
    return per_dim.any(axis=1) if combine == "any" else per_dim.all(axis=1)


def critical_mask(
    costs: np.ndarray,
    d: np.ndarray,
    eps: float,
    combine: Combine = "any",
    valid: np.ndarray | None = None,
) -> np.ndarray:
    """Membership of ``T_eps`` (eq. 4): ``(N,) bool``; invalid rows are never critical.

    ``combine="all"`` on invalid rows is still ``False`` because their per-dimension
    masks are all ``False``.
    """
    return combine_dims(critical_dims(costs, d, eps, valid), combine)


@dataclass(frozen=True)
class CriticalZone:
    """The critical zone, one concept for selection, the shield, evaluation and rendering:
    the limits ``d_s`` (the demonstrations' worst cost per dimension), the zone's width eps
    and how per-dimension flags combine. A state is critical when ``c_s >= d_s - eps``
    (combined over ``s``) and beyond the limit when ``c_s > d_s`` in any dimension.

    >>> zone = CriticalZone((5.0, 5.0), eps=1.0)
    >>> zone.critical(np.array([[4.5, 0.0], [3.0, 3.0]])).tolist()
    [True, False]
    >>> zone.beyond(np.array([[5.5, 0.0], [5.0, 5.0]])).tolist()
    [True, False]
    """

    limits: tuple[float, ...]
    """``d_s`` per safety dimension (cost units); arrays are stored as a tuple of floats."""
    eps: float
    """Width of the zone (cost units), ``>= 0``."""
    combine: Combine = "any"
    """How per-dimension flags combine: critical in ``any`` dimension or in ``all``."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "limits", tuple(float(x) for x in np.ravel(self.limits)))
        if not (math.isfinite(self.eps) and self.eps >= 0):
            raise ValueError(f"eps must be a finite number >= 0, got {self.eps!r}")
        _check_choice("combine", self.combine, get_args(Combine))

    def critical(self, costs: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
        """``(N, S) -> (N,) bool``: membership of ``T_eps`` (:func:`critical_mask`)."""
        return critical_mask(costs, np.asarray(self.limits), self.eps, self.combine, valid)

    def per_dim(self, costs: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
        """``(N, S) -> (N, S) bool``: each dimension's ``c_s >= d_s - eps``, before the
        dimensions combine (:func:`critical_dims`)."""
        return critical_dims(costs, np.asarray(self.limits), self.eps, valid)

    def beyond(self, costs: np.ndarray) -> np.ndarray:
        """``(N, S) -> (N,) bool``: a cost beyond its limit in some dimension."""
        return np.any(np.asarray(costs, np.float64) > np.asarray(self.limits), axis=1)


def segment_ids(episode_ids: np.ndarray, valid: np.ndarray, segment_steps: int) -> np.ndarray:
    """BC-Safe's segments: ``(N,) int64`` segment number of each row, ``-1`` for invalid rows.

    Each episode's valid rows, in row order, are cut into windows of ``segment_steps``
    consecutive rows (the last window of an episode may be shorter); segments are numbered
    ``0..n-1`` by episode id, then time. Rows need not be grouped by episode, but within an
    episode row order must be time order (as in :class:`safe_bc.data.demos.Demonstrations`).

    >>> segment_ids(np.array([0, 0, 0, 1, 1]), np.array([False, True, True, True, True]), 1)
    array([-1,  0,  1,  2,  3])
    >>> segment_ids(np.array([0, 0, 0, 0, 0]), np.ones(5, bool), 2)
    array([0, 0, 1, 1, 2])
    """
    episode_ids = np.asarray(episode_ids)
    valid = np.asarray(valid)
    n = len(valid)
    if episode_ids.shape != (n,):
        raise ValueError(f"episode_ids must have shape ({n},), got {episode_ids.shape}")
    if valid.dtype != bool or valid.ndim != 1:
        raise ValueError(f"valid must be a (N,) bool array, got {valid.shape} {valid.dtype}")
    if isinstance(segment_steps, bool) or int(segment_steps) != segment_steps or segment_steps < 1:
        raise ValueError(f"segment_steps must be an integer >= 1, got {segment_steps!r}")
    out = np.full(n, -1, np.int64)
    rows = np.flatnonzero(valid)
    if len(rows) == 0:
        return out
    order = rows[np.argsort(episode_ids[rows], kind="stable")]
    ep = episode_ids[order]
    new_episode = np.r_[True, ep[1:] != ep[:-1]]
    pos = np.arange(len(order))
    episode_start = np.maximum.accumulate(np.where(new_episode, pos, 0))
    rank = pos - episode_start
    out[order] = np.cumsum(new_episode | (rank % int(segment_steps) == 0)) - 1
    return out


def safe_segment_rows(mask: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """``(N,) bool``: rows of the segments with no critical row (BC-Safe's training set).

    Args:
        mask: ``(N,) bool`` membership of ``T_eps``.
        segments: ``(N,) int64`` from :func:`segment_ids` (``-1``: not in any segment).

    >>> safe_segment_rows(np.array([False, True, False, False]), np.array([0, 0, 1, -1]))
    array([False, False,  True, False])
    """
    mask = np.asarray(mask, bool)
    segments = np.asarray(segments, np.int64)
    if segments.shape != mask.shape:
        raise ValueError(f"segments {segments.shape} and mask {mask.shape} differ in shape")
    inside = segments >= 0
    if not inside.any():
        return np.zeros(len(mask), bool)
    n_seg = int(segments.max()) + 1
    hit = np.bincount(segments[inside], weights=mask[inside], minlength=n_seg) > 0
    return inside & ~hit[np.where(inside, segments, 0)]


def limit_margins(
    costs: np.ndarray, d: np.ndarray, combine: Combine = "any", valid: np.ndarray | None = None
) -> np.ndarray:
    """``(N,) float64`` margin of each row to the limit, ``g = min_s (d_s - c_s)`` (``max_s``
    for ``combine="all"``), clipped at 0 (costs beyond a quantile threshold); NaN for invalid
    rows. ``T_eps`` is ``{g <= eps}`` on the valid rows (up to float rounding at the edge).

    >>> limit_margins(np.array([[1.0, 4.0], [3.0, 0.0]]), np.array([3.0, 5.0])).tolist()
    [1.0, 0.0]
    """
    _check_choice("combine", combine, get_args(Combine))
    c, valid = _check_costs(costs, valid)
    d = np.asarray(d, np.float64)
    if d.shape != (c.shape[1],):
        raise ValueError(f"thresholds must have shape ({c.shape[1]},), got {d.shape}")
    gap = d - c
    g = gap.min(axis=1) if combine == "any" else gap.max(axis=1)
    return np.where(valid, np.maximum(g, 0.0), np.nan)


def cost_weights(
    costs: np.ndarray,
    d: np.ndarray,
    beta: float,
    combine: Combine = "any",
    valid: np.ndarray | None = None,
) -> np.ndarray:
    """Cost-weighted BC's sampling weights, ``(N,) float64``: ``1 + beta * (1 - g / g_max)`` on
    valid rows (``g``: :func:`limit_margins`, ``g_max`` its largest valid value; all rows get
    ``1 + beta`` when ``g_max == 0``), 0 on invalid rows. See ``SelectionConfig.beta``.

    >>> cost_weights(np.array([[0.0], [5.0], [10.0]]), np.array([10.0]), 4.0).tolist()
    [1.0, 3.0, 5.0]
    """
    if not (math.isfinite(beta) and beta >= 0):
        raise ValueError(f"beta must be a finite number >= 0, got beta={beta!r}")
    _, ok = _check_costs(costs, valid)
    g = limit_margins(costs, d, combine, ok)
    if not ok.any():
        raise SelectionError(f"no valid rows to weight (N={len(ok)})")
    if not np.isfinite(g[ok]).all():
        raise SelectionError(f"{int((~np.isfinite(g[ok])).sum())} valid rows have non-finite costs")
    g_max = float(g[ok].max())
    closeness = 1.0 - g / g_max if g_max > 0 else np.ones_like(g)
    return np.where(ok, 1.0 + beta * closeness, 0.0)


@dataclass(frozen=True, eq=False)
class Selection:
    """Result of ``select``: the thresholds and ``T_eps`` of one demonstration set.

    Attributes:
        config: the ``SelectionConfig`` used.
        thresholds: ``(S,) float64`` ``d_s``.
        per_dim: ``(N, S) bool`` critical per dimension.
        mask: ``(N,) bool`` membership of ``T_eps``.
        valid: ``(N,) bool`` rows that were considered (not warm-up).
        safety_dims: names of the ``S`` dimensions (for the summary), or ``None``.
        weights: ``(N,) float64`` sampling weight of every row for ``mode="bc_safe"`` (1 on
            the kept segments' rows, else 0) and ``mode="cost_weighted"`` (:func:`cost_weights`);
            ``None`` for ``mode="mix"``.
        segments: ``(N,) int64`` BC-Safe's segment of every row (:func:`segment_ids`), or
            ``None`` for the other modes.
    """

    config: SelectionConfig
    thresholds: np.ndarray
    per_dim: np.ndarray
    mask: np.ndarray
    valid: np.ndarray
    safety_dims: tuple[str, ...] | None = field(default=None)
    weights: np.ndarray | None = field(default=None)
    segments: np.ndarray | None = field(default=None)

    @property
    def zone(self) -> CriticalZone:
        """The critical zone this selection drew: ``d_s``, eps and combine."""
        return CriticalZone(self.thresholds, self.config.width, self.config.combine)

    @property
    def n_rows(self) -> int:
        return len(self.mask)

    @property
    def n_valid(self) -> int:
        return int(self.valid.sum())

    @property
    def n_critical(self) -> int:
        return int(self.mask.sum())

    @property
    def critical_per_dim(self) -> np.ndarray:
        """``(S,) int64`` number of critical rows in each dimension."""
        return self.per_dim.sum(axis=0).astype(np.int64)

    @property
    def n_train_rows(self) -> int:
        """Rows a batch can contain: the rows with a positive weight for the baselines; for
        ``mix``, ``T_eps`` when ``alpha = 1``, ``T \\ T_eps`` when ``alpha = 0`` and
        ``rest="noncritical"``, else all valid rows."""
        if self.weights is not None:
            return int((self.weights > 0).sum())
        if self.config.alpha == 1.0:
            return self.n_critical
        if self.config.rest == "noncritical" and self.config.alpha == 0.0:
            return self.n_valid - self.n_critical
        return self.n_valid

    @property
    def critical_sample_share(self) -> float:
        """Expected share of ``T_eps`` rows in a training batch (before rounding ``alpha * B``):
        ``alpha`` plus the rest pool's own share for ``mix``, the critical rows' share of the
        sampling weight for the baselines (0 for BC-Safe)."""
        if self.weights is not None:
            return float(self.weights[self.mask].sum() / self.weights.sum())
        a = self.config.alpha
        if self.config.rest == "noncritical" or a == 1.0:
            return a
        return a + (1 - a) * self.n_critical / max(self.n_valid, 1)

    def sampler(
        self, batch_size: int, rng: np.random.Generator, alpha: float | None = None
    ) -> BatchSampler:
        """The training sampler of this selection: a ``MixedBatchSampler`` for ``mode="mix"``
        (``alpha`` defaults to the config's), a ``WeightedBatchSampler`` over ``weights`` for
        the baselines (which take no ``alpha``)."""
        if self.weights is not None:
            if alpha is not None:
                raise ValueError(f"alpha applies to mode='mix' only, not {self.config.mode!r}")
            return WeightedBatchSampler(
                self.weights, batch_size, rng, mask=self.mask, valid=self.valid
            )
        return MixedBatchSampler(
            self.mask,
            self.config.alpha if alpha is None else alpha,
            batch_size,
            self.config.rest,
            rng,
            valid=self.valid,
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-able summary (no per-row arrays; persist ``mask``/``thresholds`` separately)."""
        out: dict[str, Any] = {
            "config": self.config.to_dict(),
            "safety_dims": None if self.safety_dims is None else list(self.safety_dims),
            "thresholds": [float(x) for x in self.thresholds],
            "n_rows": self.n_rows,
            "n_valid": self.n_valid,
            "n_critical": self.n_critical,
            "critical_fraction": self.n_critical / self.n_valid,
            "critical_per_dim": [int(x) for x in self.critical_per_dim],
            "mode": self.config.mode,
            "n_train_rows": self.n_train_rows,
            "critical_sample_share": self.critical_sample_share,
        }
        if self.segments is not None and self.weights is not None:
            inside = self.segments >= 0
            out["n_segments"] = len(np.unique(self.segments[inside]))
            out["n_safe_segments"] = len(np.unique(self.segments[self.weights > 0]))
        return out


def improper_subset_message(selection: Selection) -> str | None:
    """One line saying why the mix has no effect, or ``None`` when it can have one.

    The alpha mix (``mode="mix"``) changes a batch only when ``T_eps`` is a proper subset of
    the scored rows: with none critical, ``alpha > 0`` cannot be drawn (the sampler refuses
    it); with all critical, every batch is plain BC whatever ``alpha`` is. ``alpha = 0`` and
    the baselines (which ignore ``alpha``) are never flagged.
    """
    config = selection.config
    if config.mode != "mix" or config.alpha == 0.0 or selection.n_valid == 0:
        return None
    fraction = selection.n_critical / selection.n_valid
    if 0.0 < fraction < 1.0:
        return None
    names = selection.safety_dims or tuple(f"c{j}" for j in range(len(selection.thresholds)))
    limits = ", ".join(f"{n}={d:.4g}" for n, d in zip(names, selection.thresholds, strict=True))
    what, effect = (
        ("no scored row", "cannot be drawn")
        if fraction == 0.0
        else ("every scored row", "has no effect")
    )
    return (
        f"T_eps holds {what} ({selection.n_critical} of {selection.n_valid}, critical "
        f"fraction {fraction:g}) at eps={config.eps:g} (combine={config.combine!r}), so "
        f"alpha={config.alpha:g} {effect}; the cost scale: d_s {limits}; choose an eps "
        f"that leaves some scored rows on each side"
    )


def warn_if_improper_subset(selection: Selection) -> None:
    """Emit one :class:`CriticalSubsetWarning` when :func:`improper_subset_message` has one."""
    message = improper_subset_message(selection)
    if message is not None:
        warnings.warn(message, CriticalSubsetWarning, stacklevel=2)


def select(
    costs: np.ndarray,
    config: SelectionConfig,
    valid: np.ndarray | None = None,
    safety_dims: Sequence[str] | None = None,
    episode_ids: np.ndarray | None = None,
) -> Selection:
    """Thresholds and ``T_eps`` for ``costs (N, S)`` under ``config``; ``valid (N,) bool``.

    Typical use: ``select(demos.costs, cfg, demos.scored, demos.safety_dims, demos.episode_ids)``
    (:func:`safe_bc.methods.experiment.select_for`). ``episode_ids (N,)`` cut BC-Safe's segments at
    episode boundaries; ``None`` treats all rows as one episode.

    Raises:
        SelectionError: no valid rows, non-finite costs, or (``mode="bc_safe"``) no segment
            outside ``T_eps``.
    """
    d = thresholds(costs, config.threshold, config.quantile, valid)
    per_dim = critical_dims(costs, d, config.width, valid)
    _, valid_arr = _check_costs(costs, valid)
    if safety_dims is not None and len(safety_dims) != len(d):
        raise ValueError(f"{len(safety_dims)} safety_dims names for {len(d)} cost columns")
    mask = combine_dims(per_dim, config.combine)
    weights, segments = RULES[config.mode].weights(
        RuleInput(config, np.asarray(costs), d, mask, valid_arr, episode_ids)
    )
    return Selection(
        config=config,
        thresholds=d,
        per_dim=per_dim,
        mask=mask,
        valid=valid_arr.copy(),
        safety_dims=None if safety_dims is None else tuple(safety_dims),
        weights=weights,
        segments=segments,
    )


def select_with_added(
    costs: np.ndarray,
    valid: np.ndarray,
    added: np.ndarray,
    config: SelectionConfig,
    limits: np.ndarray,
    added_in: AddedIn,
    what: str = "an added",
) -> Selection:
    """``T_eps`` of the alpha mix over demonstrations plus added rows (``added (N,) bool``:
    queried states, kept self-imitation steps) under the demonstrations' limits ``d_s``
    (``limits``: an added row never widens them): the rule's (``c_s >= d_s - eps`` on valid
    rows) with the added rows taken out (``"rest"``: they join only the rest pool), as the
    rule says (``"zone"``) or all in (``"critical"``). An added row must be valid (``what``
    names it in the error)."""
    costs = np.asarray(costs, np.float64)
    valid, added = np.asarray(valid, bool), np.asarray(added, bool)
    if (added & ~valid).any():
        raise ValueError(f"{what} row must be a valid (scored) row")
    limits = np.asarray(limits, np.float64)
    per_dim = critical_dims(costs, limits, config.width, valid)
    mask = combine_dims(per_dim, config.combine)
    if added_in == "rest":
        mask = mask & ~added
        per_dim = per_dim & ~added[:, None]
    elif added_in == "critical":
        mask = mask | added
    return Selection(config, limits, per_dim, mask, valid.copy())


@dataclass(frozen=True)
class RuleInput:
    """What a selection rule sees: the config, the costs, ``d_s`` and ``T_eps``."""

    config: SelectionConfig
    """The selection asked for."""
    costs: np.ndarray
    """``(N, S)`` costs of the demonstrations."""
    limits: np.ndarray
    """``(S,)`` ``d_s``."""
    mask: np.ndarray
    """``(N,) bool`` membership of ``T_eps``."""
    valid: np.ndarray
    """``(N,) bool`` scored rows."""
    episode_ids: np.ndarray | None
    """``(N,)`` episode of each row, or ``None`` (one episode)."""


@dataclass(frozen=True)
class Rule:
    """A selection rule: which rows training draws, and how often. Adding one is an entry of
    :data:`RULES` (its mode name in :data:`Baseline`) and its weights function;
    ``tests/test_selection.py`` walks every entry."""

    weights: Callable[[RuleInput], tuple[np.ndarray | None, np.ndarray | None]]
    """``(weights (N,) or None, segments (N,) or None)``: per-row sampling weights (``None``:
    the alpha mix's two pools) and the row's segment, where the rule has segments."""
    label: Callable[[SelectionConfig], str]
    """Row label of a configuration in tables, e.g. ``BC-Safe (K=20)``."""
    params: tuple[str, ...]
    """``SelectionConfig`` fields only this rule reads (the CLI refuses them with another
    mode). The mix's ``alpha`` and ``rest`` are not listed: the baselines ignore them, so a
    study may search ``mode`` beside ``alpha``."""


def _mix(inp: RuleInput) -> tuple[None, None]:
    return None, None


def _bc_safe(inp: RuleInput) -> tuple[np.ndarray, np.ndarray]:
    config, mask, valid = inp.config, inp.mask, inp.valid
    episodes = np.zeros(len(mask), np.int64) if inp.episode_ids is None else inp.episode_ids
    segments = segment_ids(episodes, valid, config.segment_steps)
    kept = safe_segment_rows(mask, segments)
    if not kept.any():
        n_seg = len(np.unique(segments[segments >= 0]))
        raise SelectionError(
            f"BC-Safe keeps no demonstrations: all {n_seg} segments of "
            f"{config.segment_steps} consecutive scored steps enter T_eps "
            f"(eps={config.eps:g}, combine={config.combine!r}: {int(mask.sum())} of "
            f"{int(valid.sum())} scored rows critical); use a smaller segment_steps "
            f"or eps"
        )
    return kept.astype(np.float64), segments


def _cost_weighted(inp: RuleInput) -> tuple[np.ndarray, None]:
    c = inp.config
    return cost_weights(inp.costs, inp.limits, c.beta, c.combine, inp.valid), None


RULES: dict[SelectionMode, Rule] = {
    "mix": Rule(_mix, lambda c: f"alpha={c.alpha:g} (rest={c.rest})", ()),
    "bc_safe": Rule(_bc_safe, lambda c: f"BC-Safe (K={c.segment_steps})", ("segment_steps",)),
    "cost_weighted": Rule(
        _cost_weighted, lambda c: f"cost-weighted BC (beta={c.beta:g})", ("beta",)
    ),
}
"""Selection mode -> its rule (``SelectionConfig.mode``)."""


def n_critical_per_batch(alpha: float, batch_size: int) -> int:
    """``round(alpha * B)`` with halves rounded up: ``floor(alpha * B + 0.5)``.

    Python's ``round`` rounds halves to even (``round(2.5) == 2`` but ``round(3.5) == 4``),
    so ties would go to the critical pool for some ``B`` and away from it for others; rounding
    half up always gives ties to ``T_eps`` (``alpha = 0.5, B = 1`` draws one critical row).

    >>> n_critical_per_batch(0.5, 5), n_critical_per_batch(0.1, 64), round(0.5 * 5)
    (3, 6, 2)
    """
    return int(np.floor(alpha * batch_size + 0.5))


class MixedBatchSampler:
    """Index batches with a fixed safety-critical share (eq. 5).

    Each batch of ``B`` indices holds exactly ``k = n_critical_per_batch(alpha, B)`` indices
    drawn uniformly with replacement from ``T_eps`` (``mask & valid``) and ``B - k`` drawn
    uniformly with replacement from the rest pool: all valid rows (``rest="all"``) or the
    valid non-critical rows (``rest="noncritical"``). The batch is then shuffled.

    Args:
        mask: ``(N,) bool`` membership of ``T_eps``.
        alpha: safety focus in ``[0, 1]``.
        batch_size: ``B >= 1``.
        rest: ``"all"`` or ``"noncritical"`` (see ``SelectionConfig.rest``).
        rng: the only source of randomness; same seed, same batches.
        valid: ``(N,) bool`` rows allowed at all (e.g. not warm-up); ``None`` = all.

    Raises:
        SelectionError: ``alpha > 0`` with an empty ``T_eps``, ``alpha < 1`` with an
            empty rest pool, or ``batch_size < 1``.
        ValueError: invalid ``alpha``, ``rest`` or array shapes.
    """

    def __init__(
        self,
        mask: np.ndarray,
        alpha: float,
        batch_size: int,
        rest: Rest,
        rng: np.random.Generator,
        valid: np.ndarray | None = None,
    ) -> None:
        mask = np.asarray(mask)
        if mask.ndim != 1 or mask.dtype != bool:
            raise ValueError(f"mask must be a (N,) bool array, got {mask.shape} {mask.dtype}")
        n = len(mask)
        if valid is None:
            valid = np.ones(n, bool)
        valid = np.asarray(valid)
        if valid.shape != (n,) or valid.dtype != bool:
            raise ValueError(f"valid must be a ({n},) bool array, got {valid.shape} {valid.dtype}")
        if not (0.0 <= alpha <= 1.0):
            raise ValueError(f"alpha must be in [0, 1], got alpha={alpha!r}")
        if isinstance(batch_size, bool) or int(batch_size) != batch_size or batch_size < 1:
            raise SelectionError(f"batch_size must be an integer >= 1, got {batch_size!r}")
        _check_choice("rest", rest, get_args(Rest))
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng must be a numpy Generator, got {type(rng).__name__}")

        self.alpha = float(alpha)
        self.batch_size = int(batch_size)
        self.rest: Rest = rest
        self.rng = rng
        self.mask = mask.copy()
        self.valid = valid.copy()
        self.critical_pool = np.flatnonzero(mask & valid).astype(np.int64)
        rest_rows = valid if rest == "all" else valid & ~mask
        self.rest_pool = np.flatnonzero(rest_rows).astype(np.int64)
        self.n_critical = n_critical_per_batch(self.alpha, self.batch_size)
        self.n_rest = self.batch_size - self.n_critical

        counts = (
            f"N={n}, valid={int(valid.sum())}, critical={len(self.critical_pool)}, "
            f"rest pool ({rest})={len(self.rest_pool)}"
        )
        if self.alpha > 0 and len(self.critical_pool) == 0:
            raise SelectionError(f"alpha={self.alpha} > 0 but T_eps is empty ({counts})")
        if self.alpha < 1 and len(self.rest_pool) == 0:
            raise SelectionError(f"alpha={self.alpha} < 1 but the rest pool is empty ({counts})")

    def with_rng(self, rng: np.random.Generator) -> MixedBatchSampler:
        """The same sampler with a fresh random stream."""
        return MixedBatchSampler(
            self.mask, self.alpha, self.batch_size, self.rest, rng, valid=self.valid
        )

    def sample_parts(self) -> tuple[np.ndarray, np.ndarray]:
        """Unshuffled ``(critical (k,) int64, rest (B - k,) int64)`` parts of one batch."""
        crit = self.critical_pool[
            self.rng.integers(0, max(len(self.critical_pool), 1), self.n_critical)
        ]
        rest = self.rest_pool[self.rng.integers(0, max(len(self.rest_pool), 1), self.n_rest)]
        return crit, rest

    def sample(self) -> np.ndarray:
        """One shuffled batch, ``(B,) int64`` row indices."""
        crit, rest = self.sample_parts()
        return self.rng.permutation(np.concatenate([crit, rest]))

    def __repr__(self) -> str:
        return (
            f"MixedBatchSampler(alpha={self.alpha}, batch_size={self.batch_size}, "
            f"rest={self.rest!r}, critical={len(self.critical_pool)}, "
            f"rest_pool={len(self.rest_pool)}, per_batch={self.n_critical}+{self.n_rest})"
        )


class BatchSampler(Protocol):
    """What training needs of a sampler (``MixedBatchSampler``, ``WeightedBatchSampler``)."""

    mask: np.ndarray
    """``(N,) bool`` membership of ``T_eps`` (its length is the number of rows)."""
    valid: np.ndarray
    """``(N,) bool`` scored rows (input standardisation statistics come from them)."""
    batch_size: int

    def sample(self) -> np.ndarray:
        """One batch, ``(batch_size,) int64`` row indices."""
        ...

    def with_rng(self, rng: np.random.Generator) -> BatchSampler:
        """The same sampler with a fresh random stream."""
        ...


class WeightedBatchSampler:
    """Index batches drawn i.i.d. with probability proportional to per-row weights.

    BC-Safe is 0/1 weights (its kept segments), cost-weighted BC the weights of
    :func:`cost_weights`. Each of the ``B`` indices is ``searchsorted(cumsum(w), u * sum(w))``
    for ``u = rng.random(B)``, so the batches depend on ``rng`` alone.

    Args:
        weights: ``(N,)`` finite, ``>= 0``, 0 outside ``valid``, positive somewhere.
        batch_size: ``B >= 1``.
        rng: the only source of randomness; same seed, same batches.
        mask: ``(N,) bool`` membership of ``T_eps`` (for reporting only); ``None``: none.
        valid: ``(N,) bool`` scored rows; ``None``: the rows with a positive weight.

    Raises:
        SelectionError: all weights are 0, or ``batch_size < 1``.
        ValueError: bad shapes, negative or non-finite weights, weight outside ``valid``.

    >>> s = WeightedBatchSampler(np.array([0.0, 1.0, 3.0]), 1000, np.random.default_rng(0))
    >>> counts = np.bincount(s.sample(), minlength=3); int(counts[0]), bool(counts[2] > counts[1])
    (0, True)
    """

    def __init__(
        self,
        weights: np.ndarray,
        batch_size: int,
        rng: np.random.Generator,
        *,
        mask: np.ndarray | None = None,
        valid: np.ndarray | None = None,
    ) -> None:
        weights = np.asarray(weights, np.float64)
        if weights.ndim != 1:
            raise ValueError(f"weights must be a (N,) array, got shape {weights.shape}")
        n = len(weights)
        if not np.isfinite(weights).all() or (weights < 0).any():
            raise ValueError("weights must be finite and >= 0")
        mask = np.zeros(n, bool) if mask is None else np.asarray(mask)
        valid = weights > 0 if valid is None else np.asarray(valid)
        for name, arr in (("mask", mask), ("valid", valid)):
            if arr.shape != (n,) or arr.dtype != bool:
                raise ValueError(f"{name} must be a ({n},) bool array, got {arr.shape} {arr.dtype}")
        if (weights[~valid] > 0).any():
            raise ValueError(f"{int((weights[~valid] > 0).sum())} rows outside valid have weight")
        if isinstance(batch_size, bool) or int(batch_size) != batch_size or batch_size < 1:
            raise SelectionError(f"batch_size must be an integer >= 1, got {batch_size!r}")
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng must be a numpy Generator, got {type(rng).__name__}")
        if not (weights > 0).any():
            raise SelectionError(f"every sampling weight is 0 (N={n}, valid={int(valid.sum())})")
        self.weights = weights.copy()
        self.batch_size = int(batch_size)
        self.rng = rng
        self.mask = mask.copy()
        self.valid = valid.copy()
        self._cdf = np.cumsum(self.weights)

    def with_rng(self, rng: np.random.Generator) -> WeightedBatchSampler:
        """The same sampler with a fresh random stream."""
        return WeightedBatchSampler(
            self.weights, self.batch_size, rng, mask=self.mask, valid=self.valid
        )

    @property
    def probabilities(self) -> np.ndarray:
        """``(N,) float64`` probability of each row per draw."""
        return self.weights / self._cdf[-1]

    def sample(self) -> np.ndarray:
        """One batch, ``(B,) int64`` row indices (i.i.d., with replacement)."""
        u = self.rng.random(self.batch_size) * self._cdf[-1]
        idx = np.searchsorted(self._cdf, u, side="right")
        return np.minimum(idx, len(self._cdf) - 1).astype(np.int64)

    def __repr__(self) -> str:
        w = self.weights[self.weights > 0]
        return (
            f"WeightedBatchSampler(batch_size={self.batch_size}, rows={len(w)}, "
            f"weights {w.min():.3g}..{w.max():.3g})"
        )
