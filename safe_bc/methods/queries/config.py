"""The settings of a critical-zone query run and its fixed names (stdlib only, so that a study
file or the CLI reads :class:`QueryConfig` without importing torch or Ray)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Any, Literal, get_args

from safe_bc.methods.layout import DONE, IDENTITY, POLICY, round_dir  # noqa: F401 (the run folder)

QueryMode = Literal["critical", "full"]

QUERY_SEED_BASE = (1 << 29) + (1 << 28)
"""Rollout tracks (patients) of run ``seed``, round ``r``, episode ``k`` are
``QUERY_SEED_BASE + seed * 10**6 + r * 10**4 + k``: above the demonstration seeds (below
``2**29``) and the improvement stage's training seeds (``2**29 + seed * 10**6 + k``, below
``QUERY_SEED_BASE`` for seeds < 268), below the held-out evaluation seeds (``2**30``)."""
_PER_SEED = 1_000_000
_PER_ROUND = 10_000
FORMAT = "safe_bc.queries/1"
QUERIES = "queries.npz"


def track_seeds(seed: int, r: int, n: int) -> list[int]:
    """The ``n`` rollout tracks of round ``r`` of run ``seed``.

    >>> track_seeds(0, 1, 2) == [QUERY_SEED_BASE + 10_000, QUERY_SEED_BASE + 10_001]
    True
    """
    if not (0 <= seed < 268 and 0 <= r < 100 and 0 <= n <= _PER_ROUND):
        raise ValueError(f"seed in [0, 268), round in [0, 100), n <= {_PER_ROUND}: {seed, r, n}")
    return [QUERY_SEED_BASE + seed * _PER_SEED + r * _PER_ROUND + k for k in range(n)]


@dataclass(frozen=True)
class QueryConfig:
    """One interactive-imitation run: roll the agent out, ask the expert, retrain, repeat."""

    mode: QueryMode = "critical"
    """``"critical"``: the expert is asked only at visited scored states in the critical zone
    (``c_s >= d_s - eps`` in some dimension, the selection's own definition: entering the zone
    or beyond ``d_s``); ``"full"``: at every visited scored state (DAgger)."""
    rounds: int = 2
    """Rounds of roll-out, query and retraining. 2 fits the measurement's 10-minute budget
    on 16 cores (the queries family, ``tune_jobs/compare/queries.py``); more rounds need a
    longer run to choose."""
    episodes_per_round: int = 16
    """Rollout episodes (training tracks, :func:`track_seeds`) per round: one per core of
    the 16-core measurement machine."""
    eps: float | None = None
    """Width of the query zone in cost units; ``None``: the selection's eps (T_eps itself)."""
    query_budget: int | None = None
    """At most this many queries per round (``None``: no cap). The kept queries are the first
    in (track, step) order: what an expert who stops after this many labels gives. The
    comparison gives ``full`` the number the ``critical`` run used."""
    budget_of: str = ""
    """A comparison row of this method whose run sets :attr:`query_budget` (``""``: none): per
    round, its total queries over this run's rounds, rounded up (at least 1), that run's
    same training seed; e.g. DAgger (``"full"``) at the critical-zone run's number of queries.
    The comparison runner resolves it after that row's run (:meth:`with_budget`)."""
    batches: int | None = None
    """BC batches of each retraining (``None``: the run config's ``bc.train.batches``)."""
    max_steps: int | None = None
    """Step cap per rollout episode (``None``: the env's time limit)."""
    workers: int = 0
    """Rollout actors (Ray); 0 rolls out in this process. The study stage keeps 0 unless
    its trials reserve CPUs for the actors."""
    seed: int = 0
    """Picks the rollout tracks; the study stage sets it to the training seed."""

    def __post_init__(self) -> None:
        if self.mode not in get_args(QueryMode):
            raise ValueError(f"mode must be one of {get_args(QueryMode)}, got {self.mode!r}")
        for name in ("rounds", "episodes_per_round"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        for name in ("query_budget", "batches", "max_steps"):
            value = getattr(self, name)
            if value is not None and int(value) < 1:
                raise ValueError(f"{name} must be >= 1 or None, got {value}")
        if self.eps is not None and not (math.isfinite(self.eps) and self.eps >= 0):
            raise ValueError(f"eps must be a finite number >= 0, got {self.eps}")
        if self.workers < 0 or self.seed < 0:
            raise ValueError(f"workers and seed must be >= 0, got {self.workers}, {self.seed}")
        if self.budget_of and self.query_budget is not None:
            raise ValueError("set query_budget or budget_of, not both")

    def with_budget(self, total_queries: int) -> QueryConfig:
        """This config with :attr:`budget_of` resolved: that run asked ``total_queries``.

        >>> QueryConfig(mode="full", budget_of="critical").with_budget(7).query_budget
        4
        """
        budget = max(1, math.ceil(int(total_queries) / self.rounds))
        return replace(self, query_budget=budget, budget_of="")

    def to_dict(self) -> dict[str, Any]:
        """JSON-able field dict (``budget_of`` only where set: records of runs without one
        stay what they were)."""
        out = asdict(self)
        if not out["budget_of"]:
            del out["budget_of"]
        return out

    def identity(self) -> dict[str, Any]:
        """The fields that change the run's data or weights (``workers`` does not)."""
        out = self.to_dict()
        out.pop("workers")
        return out
