"""Beyond the expert: constrained RL that starts from a safety-imitation agent (PPO-Lagrangian).

A safety-imitation agent (a :class:`~safe_bc.bc.BCNet` checkpoint from ``safe-bc train``)
copies the expert, limits included. This module improves it on the env's reward while
keeping every step within the expert's limits ``d_s`` (:attr:`Demonstrations.limits`, the
worst expert cost per dimension). Two mechanisms, each switchable in :class:`ImproveConfig`:

* **critical-state shield** (``shield=True``): in a state inside the critical zone
  ``T_eps = {c_s >= d_s - eps}`` (:func:`safe_bc.selection.critical_mask`, with the start's
  eps and combine rule), the action comes from the frozen imitation start; elsewhere from the
  improving policy. The shield reads the *measured* costs of the state, computed from the
  observation (:func:`observed_costs`), so it needs nothing a deployed policy lacks. Shielded
  steps are not the improving policy's choices: they train the critics but are left out of
  the policy loss.
* **Lagrangian** (``lagrangian=True``, PPO-Lagrangian): a per-step violation cost (1 when the
  step's outcome is beyond ``d_s`` in some dimension, or how far beyond), its own critic, and
  a multiplier ``lambda >= 0`` learned by projected gradient ascent on ``J_c - budget``
  (:func:`multiplier_update`); the policy ascends ``(A_r - lambda A_c) / (1 + lambda)``.

The policy is a Gaussian whose mean is the BC net itself (a copy of the start's weights, with
its input standardisation and its squashing to the action bounds) and whose log-std is one
learned parameter per action dimension; the env clips samples to its action box. An anchor
keeps it near its start: a BC term on the demonstrations (drawn with the start's own
alpha-mixed sampler) or a KL to the frozen start on the visited states.

Why a short PPO here and not a library: the shield overrides actions per state and those
steps must leave the policy gradient, and the actor must *be* the BC net; OmniSafe (the
maintained PPO-Lagrangian) owns its actors and rollouts and pins ``pandas==2.0.3`` and
safety-gymnasium's gymnasium, incompatible with this project; Stable-Baselines3 has no
Lagrangian. So, cleanrl style: one small package, one config, explicit seeds.

Determinism: every random draw comes from one ``np.random.Generator`` (minibatches, anchor
batches), one ``torch.Generator`` (action noise) or ``torch.manual_seed(seed)`` (critic
initialisation), and env seeds come from a counter; with 1 thread and the same config two
runs give bit-identical weights. Each iteration runs ``episodes_per_iter`` complete episodes
on ``n_envs`` envs in lockstep: the learner makes one batched forward pass per step (its own
noise, its own shield) and an :class:`EnvGroup` steps the envs, in this process
(:class:`LocalEnvs`, right for the rehabilitation env's ~60 us steps) or on persistent Ray
actors (:class:`safe_bc.distributed.envs.RayEnvs`, for CarRacing's milliseconds of rendering
per step). Where the envs step changes nothing else, so both give bit-identical runs; a
rollout whose actor died is run again from the same noise state. Every ``checkpoint_every``
iterations the whole state (nets, optimisers, multiplier, both generators, counters,
history) is written atomically to ``OUT/state.pt``; rerunning the same call resumes from it
and ends bit-identical to an uninterrupted run.

The package, by job (every name is importable from ``safe_bc.methods.improve`` itself):

* :mod:`~safe_bc.methods.improve.config`: :class:`ImproveConfig`, seed bases, file names (no torch);
* :mod:`~safe_bc.methods.improve.shield`: :func:`observed_costs`, :class:`Shield`,
  :class:`ShieldedPolicy`, :class:`ImprovedSource` (a finished run's agent);
* :mod:`~safe_bc.methods.improve.envs`: :class:`EnvGroup`, :class:`LocalEnvs`, the training and
  validation seeds, :class:`Rollout`;
* :mod:`~safe_bc.methods.improve.nets`: :class:`GaussianActor`, :func:`make_critic`, :func:`gae`,
  :func:`multiplier_update`;
* :mod:`~safe_bc.methods.improve.engine`: the start checkpoint and :class:`Improver` (rollouts,
  updates, one iteration);
* :mod:`~safe_bc.methods.improve.run`: :func:`improve` (resumable, checkpointed) and
  :func:`improve_from_net`.

Only :mod:`~safe_bc.methods.improve.config` is imported with the package; the other modules (torch)
on first use of one of their names, so importing ``safe_bc.methods.improve`` or its config stays
torch-free.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from safe_bc.methods.improve.config import _TRAIN_SEEDS_PER_RUN as _TRAIN_SEEDS_PER_RUN
from safe_bc.methods.improve.config import FORMAT as FORMAT
from safe_bc.methods.improve.config import HISTORY as HISTORY
from safe_bc.methods.improve.config import POLICY as POLICY
from safe_bc.methods.improve.config import ROLLOUT_RETRIES as ROLLOUT_RETRIES
from safe_bc.methods.improve.config import STATE as STATE
from safe_bc.methods.improve.config import TRAIN_SEED_BASE as TRAIN_SEED_BASE
from safe_bc.methods.improve.config import VALIDATION_SEED_BASE as VALIDATION_SEED_BASE
from safe_bc.methods.improve.config import Anchor as Anchor
from safe_bc.methods.improve.config import CostSignal as CostSignal
from safe_bc.methods.improve.config import ImproveConfig
from safe_bc.methods.improve.config import Keep as Keep

if TYPE_CHECKING:
    from safe_bc.methods.improve.engine import Improver
    from safe_bc.methods.improve.envs import (
        EnvGroup,
        EnvGroupFactory,
        EnvsLostError,
        LocalEnvs,
        train_env_seed,
        validation_seeds,
    )
    from safe_bc.methods.improve.nets import GaussianActor, gae, make_critic, multiplier_update
    from safe_bc.methods.improve.run import ImproveResult, improve, improve_from_net
    from safe_bc.methods.improve.shield import (
        ImprovedSource,
        Shield,
        ShieldedPolicy,
        observed_costs,
    )

_LAZY = {
    "shield": ("ImprovedSource", "Shield", "ShieldedPolicy", "observed_costs"),
    "envs": ("EnvGroup", "EnvGroupFactory", "EnvsLostError", "LocalEnvs", "Rollout", "StepOut",
             "train_env_seed", "validation_seeds"),
    "nets": ("GaussianActor", "gae", "make_critic", "multiplier_update"),
    "engine": ("Improver", "_Start", "_check_start_fits", "_load_start", "_start_meta"),
    "run": ("ImproveResult", "_copy_selection", "_finished", "_identity", "improve",
            "improve_from_net"),
}  # fmt: skip
"""Module -> the names it defines that ``safe_bc.methods.improve`` hands out on first use."""
_HOME = {name: module for module, names in _LAZY.items() for name in names}


def __getattr__(name: str) -> Any:
    """A name of the torch-side modules, imported on first use (PEP 562)."""
    if name not in _HOME:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from safe_bc.methods.improve import engine, envs, nets, run, shield

    modules = {"shield": shield, "envs": envs, "nets": nets, "engine": engine, "run": run}
    value = getattr(modules[_HOME[name]], name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_HOME})


__all__ = [
    "EnvGroup",
    "EnvGroupFactory",
    "EnvsLostError",
    "GaussianActor",
    "ImproveConfig",
    "ImproveResult",
    "ImprovedSource",
    "Improver",
    "LocalEnvs",
    "Shield",
    "ShieldedPolicy",
    "gae",
    "improve",
    "improve_from_net",
    "make_critic",
    "multiplier_update",
    "observed_costs",
    "train_env_seed",
    "validation_seeds",
]
