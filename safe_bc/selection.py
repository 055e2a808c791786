"""Safety-critical state selection and the alpha-mixed batch sampler (paper sec. 3.2, eqs. 4-5).

Pure numpy: no I/O, no torch. Given per-step safety costs ``(N, S)`` (higher is less
safe) of the expert demonstrations ``T_exp``:

* ``d_s = max_t c_s(s_t)`` per safety dimension (or a high quantile, robust to one
  outlier), over scored rows only (warm-up rows are excluded);
* ``T_eps = {(s_t, a_t) : c_s(s_t) >= d_s - eps}`` per dimension, combined over the
  ``S`` dimensions with ``any`` (critical in some direction) or ``all``;
* every training batch holds exactly ``round(alpha * B)`` pairs drawn from ``T_eps``
  and the rest from ``T_exp`` (or ``T_exp \\ T_eps``, see ``SelectionConfig.rest``).

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
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, Literal, get_args

import numpy as np

ThresholdMode = Literal["max", "quantile"]
Combine = Literal["any", "all"]
Rest = Literal["all", "noncritical"]


class SelectionError(ValueError):
    """The data cannot support the requested selection (no valid rows, empty pool, ...)."""


def _check_choice(name: str, value: object, options: tuple[str, ...]) -> None:
    if value not in options:
        raise ValueError(f"{name} must be one of {options}, got {value!r}")


@dataclass(frozen=True)
class SelectionConfig:
    """How to pick the safety-critical set ``T_eps`` and how to mix it into batches."""

    eps: float = 2.0
    """Width of the critical edge, in the cost's units (pixels for CarRacing): a row is
    critical in dimension ``s`` when ``c_s >= d_s - eps``. The default 2 px puts ~9% of the
    default CarRacing demonstrations in T_eps (the paper's 5 px was on another scale; here
    5 px from the expert's closest approach reaches the road's centre). ``eps = 0`` keeps
    only the rows at the threshold itself."""

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

    def __post_init__(self) -> None:
        if not (math.isfinite(self.eps) and self.eps >= 0):
            raise ValueError(f"eps must be a finite number >= 0, got eps={self.eps!r}")
        if not (0.0 <= self.alpha <= 1.0):
            raise ValueError(f"alpha must be in [0, 1], got alpha={self.alpha!r}")
        if not (0.0 < self.quantile <= 1.0):
            raise ValueError(f"quantile must be in (0, 1], got quantile={self.quantile!r}")
        _check_choice("threshold", self.threshold, get_args(ThresholdMode))
        _check_choice("combine", self.combine, get_args(Combine))
        _check_choice("rest", self.rest, get_args(Rest))

    def to_dict(self) -> dict[str, Any]:
        """JSON-able field dict."""
        return asdict(self)


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
    """

    config: SelectionConfig
    thresholds: np.ndarray
    per_dim: np.ndarray
    mask: np.ndarray
    valid: np.ndarray
    safety_dims: tuple[str, ...] | None = field(default=None)

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

    def sampler(
        self, batch_size: int, rng: np.random.Generator, alpha: float | None = None
    ) -> MixedBatchSampler:
        """A ``MixedBatchSampler`` over this selection (``alpha`` defaults to the config's)."""
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
        return {
            "config": self.config.to_dict(),
            "safety_dims": None if self.safety_dims is None else list(self.safety_dims),
            "thresholds": [float(x) for x in self.thresholds],
            "n_rows": self.n_rows,
            "n_valid": self.n_valid,
            "n_critical": self.n_critical,
            "critical_fraction": self.n_critical / self.n_valid,
            "critical_per_dim": [int(x) for x in self.critical_per_dim],
        }


def select(
    costs: np.ndarray,
    config: SelectionConfig,
    valid: np.ndarray | None = None,
    safety_dims: Sequence[str] | None = None,
) -> Selection:
    """Thresholds and ``T_eps`` for ``costs (N, S)`` under ``config``; ``valid (N,) bool``.

    Typical use: ``select(demos.costs, cfg, demos.scored, demos.safety_dims)``.
    """
    d = thresholds(costs, config.threshold, config.quantile, valid)
    per_dim = critical_dims(costs, d, config.eps, valid)
    _, valid_arr = _check_costs(costs, valid)
    if safety_dims is not None and len(safety_dims) != len(d):
        raise ValueError(f"{len(safety_dims)} safety_dims names for {len(d)} cost columns")
    return Selection(
        config=config,
        thresholds=d,
        per_dim=per_dim,
        mask=combine_dims(per_dim, config.combine),
        valid=valid_arr.copy(),
        safety_dims=None if safety_dims is None else tuple(safety_dims),
    )


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
