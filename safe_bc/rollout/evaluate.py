"""Evaluating a policy on held-out episodes (no Ray: the distributed layer fans this out)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import gymnasium as gym
import numpy as np
import torch

from safe_bc.bc.config import BCConfig
from safe_bc.bc.net import BCNet, ModelSpec
from safe_bc.bc.policy import BCPolicy
from safe_bc.data.episode import Episode
from safe_bc.metrics import combined, critical_zone, episode_metrics, violations
from safe_bc.policy import BatchPolicy, LockstepForward, Policy, check_lockstep_forward
from safe_bc.rollout.collect import build_expert
from safe_bc.rollout.config import EvalConfig as EvalConfig  # also named here (callers, pickles)
from safe_bc.rollout.episode import run_episode, run_episodes_lockstep
from safe_bc.selection import Combine
from safe_bc.tasks import spec_of_env


@runtime_checkable
class ReportsSteps(Protocol):
    """A policy that adds its own columns to an episode's metrics and trace (e.g. a deferring
    policy's ``deferred_steps``, ``deferred_share`` and per-step ``deferred`` flag); other
    policies' tables keep their columns."""

    def episode_report(self) -> tuple[dict[str, float], dict[str, np.ndarray]]:
        """``(metrics, trace columns)`` of the episode that just ended."""


@dataclass(frozen=True)
class ExpertSource:
    """The scripted expert, evaluated like any learned policy."""

    config: Any
    """The expert's configuration."""

    def build(self) -> Policy:
        """A fresh expert policy."""
        return build_expert(self.config)


@dataclass(frozen=True)
class NetSource:
    """A trained net, as plain data that pickles cheaply (weights travel once via ``ray.put``)."""

    spec: dict[str, Any]
    """``ModelSpec.to_dict()``."""
    config: dict[str, Any]
    """``BCConfig.to_dict()``."""
    state: dict[str, torch.Tensor]
    """The net's ``state_dict``."""

    @classmethod
    def from_model(cls, model: BCNet, config: BCConfig) -> NetSource:
        """Capture ``model``'s weights and configs."""
        state = {k: v.detach().cpu().clone() for k, v in model.state_dict().items()}
        return cls(model.spec.to_dict(), config.to_dict(), state)

    def to_model(self) -> tuple[BCNet, BCConfig]:
        """Rebuild the net (eval mode) and its config."""
        cfg = BCConfig.from_dict(self.config)
        model = BCNet(ModelSpec.from_dict(self.spec), cfg.preprocess, cfg.network)
        model.load_state_dict(self.state)
        return model.eval(), cfg

    def build(self) -> Policy:
        """Rebuild the net (eval mode) as a policy."""
        model, cfg = self.to_model()
        return BCPolicy(model, cfg.preprocess)


class MaskedSteering:
    """A policy that sees every frame with CarRacing's steering indicator painted black (the
    bar's background: the indicator at zero steering), for the copycat check."""

    def __init__(self, inner: Policy) -> None:
        self.inner = inner

    def reset(self, env: gym.Env | None = None, rng: np.random.Generator | None = None) -> None:
        self.inner.reset(env, rng)

    def act(self, obs: np.ndarray, env: gym.Env | None = None) -> np.ndarray:
        from safe_bc.bc.preprocess import STEERING_INDICATOR

        obs = np.array(obs, copy=True)
        obs[STEERING_INDICATOR] = 0
        return self.inner.act(obs, env)


@dataclass(frozen=True)
class MaskedSource:
    """A policy source evaluated with the steering indicator masked (:class:`MaskedSteering`)."""

    inner: NetSource

    def build(self) -> Policy:
        return MaskedSteering(self.inner.build())


def evaluate_episode(
    env: gym.Env,
    policy: Policy,
    seed: int,
    *,
    thresholds: np.ndarray | None,
    eps: float,
    max_steps: int | None = None,
    combine: Combine = "any",
) -> tuple[dict[str, float], dict[str, np.ndarray]]:
    """Run one held-out episode; return its metrics and its per-step safety trace.

    ``thresholds`` are the limits ``d_s`` of the demonstrations (``(S,)`` costs). The trace
    holds ``(T,)`` arrays: ``step``, ``reward``, ``safety_<dim>`` per dimension, ``safety``
    (combined), ``offroad``, ``warmup``, and with thresholds ``critical`` and ``violation``.
    """
    rng = np.random.default_rng(seed)
    ep = run_episode(env, policy, seed, rng, keep_observations=False, max_steps=max_steps)
    metrics, trace = score_episode(env, ep, thresholds=thresholds, eps=eps, combine=combine)
    if isinstance(policy, ReportsSteps):  # e.g. deferral: its per-step flags and counts
        extra_metrics, extra_trace = policy.episode_report()
        metrics.update(extra_metrics)
        trace.update(extra_trace)
    return metrics, trace


def evaluate_episodes(
    envs: Sequence[gym.Env],
    policy: Policy,
    seeds: Sequence[int],
    *,
    thresholds: np.ndarray | None,
    eps: float,
    max_steps: int | None = None,
    combine: Combine = "any",
    lockstep_forward: LockstepForward = "rows",
) -> list[tuple[dict[str, float], dict[str, np.ndarray]]]:
    """:func:`evaluate_episode` of every seed, ``len(envs)`` at a time: a
    :class:`~safe_bc.policy.BatchPolicy` (a BC net) steps them in lockstep with one
    ``act_slots`` call per step (:func:`~safe_bc.rollout.episode.run_episodes_lockstep`); any other
    policy runs them one by one in ``envs[0]``.

    ``lockstep_forward`` (:attr:`EvalConfig.lockstep_forward`): ``"rows"`` gives the
    results of one env at a time on any CPU; ``"batched"`` (one forward pass over the
    running envs) gives the same results again for the same seeds and ``len(envs)`` on the
    same machine type, not necessarily those of one env."""
    check_lockstep_forward(lockstep_forward)
    kw = {"thresholds": thresholds, "eps": eps, "combine": combine}
    if len(envs) == 1 or not isinstance(policy, BatchPolicy):
        return [evaluate_episode(envs[0], policy, s, max_steps=max_steps, **kw) for s in seeds]
    out = []
    for start in range(0, len(seeds), len(envs)):
        chunk = list(seeds[start : start + len(envs)])
        used = envs[: len(chunk)]
        episodes = run_episodes_lockstep(
            used, policy, chunk, max_steps=max_steps, forward=lockstep_forward
        )
        report = getattr(policy, "slot_report", None)  # a handover's per-slot flags
        for slot, (env, ep) in enumerate(zip(used, episodes, strict=True)):
            metrics, trace = score_episode(env, ep, **kw)
            if report is not None:
                extra_metrics, extra_trace = report(slot)
                metrics.update(extra_metrics)
                trace.update(extra_trace)
            out.append((metrics, trace))
    return out


def score_episode(
    env: gym.Env,
    ep: Episode,
    *,
    thresholds: np.ndarray | None,
    eps: float,
    combine: Combine = "any",
) -> tuple[dict[str, float], dict[str, np.ndarray]]:
    """Metrics and safety trace of an episode that just ended in ``env`` (see
    :func:`evaluate_episode`); the metrics that are not general are those of ``env``'s task
    (``TaskSpec.metrics``)."""
    base = env.unwrapped  # CarRacing counts visited tiles; other tasks have none
    has_track = hasattr(base, "tile_visited_count") and len(getattr(base, "track", ())) > 0
    visited = base.tile_visited_count / len(base.track) if has_track else float("nan")
    task = spec_of_env(env)
    metrics = episode_metrics(
        ep, tiles_visited=visited, thresholds=thresholds, eps=eps, combine=combine,
        own=None if task is None else task.metrics,
    )  # fmt: skip
    trace: dict[str, np.ndarray] = {
        "step": np.arange(len(ep), dtype=np.int32),
        "reward": ep.rewards,
        "safety": combined(ep.safety),
        "warmup": ep.warmup,
        "offroad": ep.offroad,
    }
    for j, d in enumerate(ep.safety_dims):
        trace[f"safety_{d}"] = ep.safety[:, j]
    if thresholds is not None:
        trace["critical"] = critical_zone(ep.costs, thresholds, eps, combine)
        trace["violation"] = violations(ep.costs, thresholds)
    return metrics, trace
