"""How a policy is evaluated (:class:`EvalConfig`): plain data, importable without torch, so
that the command line's records can name its defaults."""

from __future__ import annotations

from dataclasses import dataclass, field

from safe_bc.policy import LockstepForward, check_lockstep_forward
from safe_bc.seeds import heldout_seed
from safe_bc.selection import DEFAULT_EPS, Combine
from safe_bc.tasks.env_config import EnvConfig


@dataclass(frozen=True)
class EvalConfig:
    """How a policy is evaluated."""

    episodes: int = 10
    """Held-out episodes per policy (the paper used 2)."""
    workers: int = 2
    """Persistent evaluation actors; 0 evaluates in the calling process."""
    seed: int = 0
    """Evaluation seed: picks the block of held-out track seeds."""
    first_episode: int = 0
    """Index of the first held-out seed of the block to use: episodes ``first_episode ..
    first_episode + episodes - 1`` (a trial's second evaluation round continues where its
    screening stopped; final-phase seeds each get their own tracks)."""
    env: EnvConfig = field(default_factory=EnvConfig)
    """The environment."""
    max_steps: int | None = None
    """Step cap per episode (``None``: the env's time limit)."""
    eps: float = DEFAULT_EPS
    """Width of the critical zone used for ``critical_share`` (the selection's eps)."""
    combine: Combine = "any"
    """How per-dimension critical flags combine for ``critical_share`` (the selection's)."""
    lockstep_forward: LockstepForward = field(default="batched", repr=False)
    """How a BC net acts for the envs a worker steps in lockstep (``envs_per_worker > 1`` of
    :func:`safe_bc.distributed.evaluate.evaluate_policies`; other policies and one env per
    worker ignore it): ``"batched"`` (default), one forward pass over the running envs, is
    faster per frame, but its episodes are only reproducible on the same machine type with the
    same number of envs and torch threads (a batched pass rounds differently from one-row
    ones, and differently on other CPUs: :data:`safe_bc.policy.LockstepForward`); ``"rows"``,
    one forward pass per env, gives every episode exactly as one env at a time would, on any
    CPU. The default was chosen by ``make bench`` (the ``eval`` case: evaluation episodes per
    minute per core of the raster env with 4 envs in lockstep against the exact one-env path,
    ``results/bench.parquet``): only the batched pass reached 2x. Episodes are dealt to
    lockstep groups by seed order (fixed groups of ``envs_per_worker``), never by how many
    workers run, so a result does not depend on the cluster's size.
    Left out of the repr, so that the keys of evaluations stored before this field existed
    (the final phase keys the config's repr) still hold; where ``"batched"`` is used it is
    keyed explicitly (the final phase's keys, :mod:`safe_bc.compare.run`'s stamps)."""

    def seeds(self) -> list[int]:
        """The held-out env seeds this evaluation runs, in order."""
        return [heldout_seed(self.seed, self.first_episode + k) for k in range(self.episodes)]

    def __post_init__(self) -> None:
        if self.episodes < 1:
            raise ValueError(f"episodes must be >= 1, got {self.episodes}")
        if self.workers < 0:
            raise ValueError(f"workers must be >= 0, got {self.workers}")
        if self.first_episode < 0:
            raise ValueError(f"first_episode must be >= 0, got {self.first_episode}")
        if self.eps < 0:
            raise ValueError(f"eps must be >= 0, got {self.eps}")
        check_lockstep_forward(self.lockstep_forward)
