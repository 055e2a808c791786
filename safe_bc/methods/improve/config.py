"""The settings of an improvement run and its fixed names (seed bases, file names, format).

Stdlib only, so that a study file or the CLI can read :class:`ImproveConfig` without
importing torch, pandas or Ray (the ``safe_bc`` package itself imports gymnasium and numpy to
register its envs).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Any, Literal, get_args

CostSignal = Literal["indicator", "excursion"]
Anchor = Literal["bc", "kl", "none"]
Keep = Literal["last", "best_feasible"]

TRAIN_SEED_BASE = 1 << 29
"""Training patients (tracks) of run ``seed`` are ``TRAIN_SEED_BASE + seed * 10**6 + k``:
disjoint from demonstration seeds (below ``2**29`` for collection seeds < 5368) and from
held-out evaluation seeds (at and above ``2**30``)."""
VALIDATION_SEED_BASE = TRAIN_SEED_BASE - 1
"""Validation patients (the learning curves) are ``VALIDATION_SEED_BASE - k``, the same for
every run."""
_TRAIN_SEEDS_PER_RUN = 1_000_000
STATE = "state.pt"
HISTORY = "history.parquet"
POLICY = "policy"
FORMAT = "safe_bc.improve/1"
ROLLOUT_RETRIES = 3
"""How often one rollout is run again after its env group lost envs."""


@dataclass(frozen=True)
class ImproveConfig:
    """One constrained improvement run (PPO-Lagrangian with an optional shield)."""

    shield: bool = True
    """Critical-state shield: in states with measured cost within ``eps`` of ``d_s`` the
    frozen imitation start acts."""
    lagrangian: bool = True
    """PPO-Lagrangian on the violation cost; ``False``: the multiplier stays at 0 and the
    policy sees the reward only."""
    eps: float | None = None
    """Width of the shield's critical zone in cost units; ``None``: the start's selection eps."""
    cost_signal: CostSignal = "indicator"
    """Per-step cost of the Lagrangian, read off the step's outcome (the next state's true
    costs): ``"indicator"`` 1 when beyond ``d_s - cost_margin`` in some dimension,
    ``"excursion"`` how far beyond (largest over the dimensions, in cost units)."""
    cost_margin: float | None = None
    """Tightens the Lagrangian's limit to ``d_s - cost_margin`` (0: exactly ``d_s``), so the
    deterministic policy keeps a margin that the noisy training policy is charged for: a
    safety margin *inside* ``d_s``, in the task's cost units. ``None``: the task's
    (``TaskSpec.cost_margin``, resolved by the run from its start's env: rehab 0.05, CarRacing
    1 px). Rehab's 0.05 from the rehab margin sweep (``tune_jobs/compare/margin_sweep.py``,
    ``results/improve/rehab/sweep/margin_sweep.md``, 3 training seeds x 512 selection patients
    disjoint from the held-out ones): its rule (the highest selection gain among the candidates
    with no selection programme beyond ``d_s``) chose the shield + Lagrangian with margin 0.05
    and a shield zone of 0.1 (``eps``, which ``improve_rehab`` of ``tune_jobs/compare/improve.py``
    sets);
    Lagrangian only with margins 0.02 / 0.05 / 0.1 let 7 / 4 / 1 of 1536 cross. CarRacing
    passes its own margin in px (``tune_jobs/compare/improve.py``: 1 px)."""
    cost_budget: float = 0.1
    """Allowed expected cost per episode of the *stochastic* training policy at the tightened
    limit, ``J_c <= budget``. With 0 the exploration noise alone keeps the multiplier rising
    forever (it can never fall), and the reward signal fades as ``1 / (1 + lambda)``."""
    lambda_init: float = 0.0
    """Initial multiplier."""
    lambda_lr: float = 0.1
    """Step size of the multiplier's projected gradient ascent, per iteration."""
    lambda_max: float = 100.0
    """Upper clip of the multiplier (keeps the reward term from vanishing entirely)."""
    anchor: Anchor = "bc"
    """What keeps the policy near its start: ``"bc"`` the start's BC loss on demonstration
    batches (the start's alpha mix), ``"kl"`` ``KL(pi || pi_start)`` on the visited states
    (start std = ``init_std``), ``"none"``."""
    anchor_coef: float = 1.0
    """Weight of the anchor term in the policy loss."""
    anchor_batch: int = 256
    """Demonstration pairs per anchor batch (``anchor="bc"``)."""
    iterations: int = 200
    """PPO iterations; each collects ``episodes_per_iter`` complete episodes."""
    episodes_per_iter: int = 64
    """Episodes (patients) per iteration."""
    n_envs: int = 64
    """Envs stepped in lockstep (episodes run in waves of this size)."""
    update_epochs: int = 10
    """Passes over each iteration's steps."""
    minibatch_size: int = 256
    """Steps per gradient step."""
    lr: float = 3e-4
    """Adam learning rate of the policy (mean net and log-std)."""
    critic_lr: float = 1e-3
    """Adam learning rate of the reward and cost critics."""
    critic_hidden: int = 128
    """Width of the critics' hidden layers (same depth and body as the BC net)."""
    critic_warmup: int = 5
    """First iterations that fit the critics only (the policy stays at its start)."""
    gamma: float = 0.99
    """Discount."""
    gae_lambda: float = 0.95
    """GAE lambda."""
    clip_coef: float = 0.2
    """PPO ratio clip."""
    target_kl: float | None = 0.02
    """Stop an iteration's epochs once the approximate KL to the rollout policy exceeds
    this; ``None``: never."""
    max_grad_norm: float = 0.5
    """Gradient norm clip (policy and critics)."""
    init_std: float = 0.1
    """Initial action std (action units; the rehab action box is ``[-1, 1]``)."""
    ent_coef: float = 0.0
    """Entropy bonus."""
    eval_every: int = 10
    """Evaluate the deterministic policy (mean action, shield as configured) on the
    validation patients every this many iterations (0: never)."""
    eval_episodes: int = 128
    """Validation patients (:data:`VALIDATION_SEED_BASE`)."""
    keep: Keep = "best_feasible"
    """Which policy the run writes: ``"last"``, or ``"best_feasible"``: the validated policy
    with the highest validation reward among those with no session beyond ``d_s`` on any
    validation patient (the last one if none qualifies). Validation patients are disjoint
    from training and held-out evaluation patients."""
    checkpoint_every: int = 10
    """Write ``state.pt`` every this many iterations (and at the end)."""
    seed: int = 0
    """Seeds the generators and picks the training patients."""
    num_threads: int = 1
    """``torch.set_num_threads`` during the run (bit-identical weights need the same)."""

    def __post_init__(self) -> None:
        for name in ("eps", "cost_margin", "cost_budget", "lambda_init", "lambda_lr",
                     "lambda_max", "anchor_coef", "lr", "critic_lr", "gamma", "gae_lambda",
                     "clip_coef", "target_kl", "max_grad_norm", "init_std",
                     "ent_coef"):  # fmt: skip
            value = getattr(self, name)
            if value is not None and not math.isfinite(value):
                raise ValueError(f"{name} must be finite, got {value}")
        if self.cost_signal not in get_args(CostSignal):
            raise ValueError(f"cost_signal must be one of {get_args(CostSignal)}")
        if self.anchor not in get_args(Anchor):
            raise ValueError(f"anchor must be one of {get_args(Anchor)}")
        if self.keep not in get_args(Keep):
            raise ValueError(f"keep must be one of {get_args(Keep)}")
        for name in ("iterations", "episodes_per_iter", "n_envs", "update_epochs",
                     "minibatch_size", "anchor_batch", "eval_episodes", "checkpoint_every",
                     "num_threads"):  # fmt: skip
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        for name in ("cost_margin", "cost_budget", "lambda_init", "lambda_lr", "anchor_coef",
                     "critic_warmup", "ent_coef", "eval_every", "seed"):  # fmt: skip
            if getattr(self, name) is not None and not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        for name in ("lr", "critic_lr", "init_std", "clip_coef", "max_grad_norm", "lambda_max"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if self.eps is not None and not self.eps >= 0:
            raise ValueError(f"eps must be >= 0, got {self.eps}")
        if not (0 <= self.gamma <= 1 and 0 <= self.gae_lambda <= 1):
            raise ValueError("gamma and gae_lambda must be in [0, 1]")

    def to_dict(self) -> dict[str, Any]:
        """JSON-able field dict."""
        return asdict(self)

    def for_margin(self, task_margin: float) -> ImproveConfig:
        """This config with ``task_margin`` (the task's ``TaskSpec.cost_margin``) where
        :attr:`cost_margin` is left at ``None``: what a run executes and records."""
        if self.cost_margin is not None:
            return self
        return replace(self, cost_margin=float(task_margin))

    @property
    def mode(self) -> str:
        """``"both"``, ``"shield"``, ``"lagrangian"`` or ``"ppo"`` (neither)."""
        if self.shield and self.lagrangian:
            return "both"
        return "shield" if self.shield else "lagrangian" if self.lagrangian else "ppo"
