"""The critical-state shield: measured costs, the critical zone, the shielded agent."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np

from safe_bc.bc.checkpoint import load_checkpoint, read_checkpoint_meta
from safe_bc.bc.policy import BCPolicy
from safe_bc.methods.improve.config import POLICY
from safe_bc.rollout.evaluate import NetSource
from safe_bc.selection import CriticalZone
from safe_bc.tasks.rehab import REHAB_ID


def observed_costs(obs: np.ndarray, env_id: str) -> np.ndarray:
    """The safety costs of states as measured, from their observations: ``(B, S) float64``.

    CarRacing: the costs are defined on the frame (:mod:`safe_bc.tasks.carracing.costs`), so this is
    exactly the env's cost. Rehabilitation: ``[hr_peak_hrr, fatigue, 2 * sbp_peak]`` of the
    observation, the measured (noisy) values of the env's true costs.
    """
    from safe_bc.tasks import task_defaults, task_of

    return task_defaults(task_of(env_id)).observed_costs(np.asarray(obs))


@dataclass(frozen=True)
class Shield:
    """Which states are critical: measured cost within ``eps`` of the limits ``d_s``."""

    zone: CriticalZone
    """``d_s``, eps and combine (the start's selection's, or the run's eps)."""
    env_id: str = REHAB_ID
    """Which observation-to-cost mapping applies (:func:`observed_costs`)."""

    def critical(self, obs: np.ndarray) -> np.ndarray:
        """``(B, *obs_shape) -> (B,) bool``: the measured costs in the critical zone."""
        return self.zone.critical(observed_costs(obs, self.env_id))


class ShieldedPolicy:
    """A :class:`~safe_bc.policy.Policy`: the fallback acts in critical states, else the policy.

    Both are called at every step (so frame stacks stay in step).
    """

    def __init__(self, policy: BCPolicy, fallback: BCPolicy, shield: Shield) -> None:
        self.policy, self.fallback, self.shield = policy, fallback, shield

    def reset(self, env: gym.Env | None = None, rng: np.random.Generator | None = None) -> None:
        self.policy.reset(env, rng)
        self.fallback.reset(env, rng)

    def act(self, obs: np.ndarray, env: gym.Env | None = None) -> np.ndarray:
        own, safe = self.policy.act(obs, env), self.fallback.act(obs, env)
        return safe if bool(self.shield.critical(np.asarray(obs)[None])[0]) else own


@dataclass(frozen=True)
class ImprovedSource:
    """An improved agent for :func:`safe_bc.distributed.evaluate.evaluate` (pickles cheaply)."""

    improved: NetSource
    """The improved mean net."""
    imitation: NetSource | None = None
    """The frozen start; with it the shield acts (``None``: no shield)."""
    shield: Shield | None = None
    """The shield's critical zone (needed with ``imitation``)."""

    def build(self) -> BCPolicy | ShieldedPolicy:
        """The improved net as a policy, behind the shield when there is one."""
        policy = self.improved.build()
        if self.imitation is None or self.shield is None:
            return policy
        return ShieldedPolicy(policy, self.imitation.build(), self.shield)

    @classmethod
    def from_run(cls, out: str | Path) -> ImprovedSource:
        """The agent of a finished improvement run in ``out`` (shield as the run had it)."""
        out = Path(out)
        meta = read_checkpoint_meta(out / POLICY)["extra"]["improve"]
        model, cfg = load_checkpoint(out / POLICY)
        if not meta["config"]["shield"]:
            return cls(NetSource.from_model(model, cfg))
        start, start_cfg = load_checkpoint(meta["start"])
        zone = CriticalZone(tuple(meta["limits"]), meta["eps"], meta["combine"])
        shield = Shield(zone, meta["env_id"])
        return cls(NetSource.from_model(model, cfg), NetSource.from_model(start, start_cfg), shield)
