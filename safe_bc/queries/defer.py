"""Deferral at use time: the agent acts, except where the measured cost is within a width
``w`` of ``d_s``, where the expert acts ("ask the clinician"). One job: the wrapper."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

from safe_bc.collection import build_expert
from safe_bc.policy import Policy
from safe_bc.queries.logic import ask_expert
from safe_bc.selection import CriticalZone


class DeferringPolicy:
    """A :class:`~safe_bc.policy.Policy` that defers to the expert in the zone
    ``c_s >= d_s - w`` (the state's ``info["cost"]``, the quantity ``d_s`` limits; never in
    warm-up). The agent is called at every step (its frame stack stays in step); the expert
    only where it acts. With ``hold`` > 0 a handover lasts: after a step in the zone the expert
    also acts on the next ``hold`` steps (each step in the zone starts the count again), so
    the agent does not take the car back in the middle of the expert's correction. With
    ``lookahead`` k > 0 the zone test reads the cost extrapolated k steps at its last change
    (``c + k (c - c_prev)``, per dimension): a cost rising fast (the front distance falling
    towards a corner) hands over before it reaches the zone. ``hold_on`` names the dimensions
    (indices) whose zone test starts a hold (``None``: any): a handover on the front distance
    (a corner ahead) lasts through the corner, one on a side distance ends when the cost
    leaves the zone; the count runs on the steps outside the zone. After an episode,
    :meth:`episode_report` gives ``deferred_steps``, ``deferred_share`` (of the episode's
    steps) and the per-step ``deferred`` flag, which the evaluation adds to its rows
    (:class:`safe_bc.evaluation.ReportsSteps`)."""

    def __init__(
        self,
        agent: Policy,
        expert: Policy,
        zone: CriticalZone,
        hold: int = 0,
        lookahead: int = 0,
        hold_on: tuple[int, ...] | None = None,
    ) -> None:
        if hold < 0 or lookahead < 0:
            raise ValueError(f"hold and lookahead must be >= 0 steps, got {hold}, {lookahead}")
        dims = len(zone.limits)
        if hold_on is not None and not all(0 <= int(i) < dims for i in hold_on):
            raise ValueError(f"hold_on must be dimension indices in [0, {dims}), got {hold_on}")
        self.agent, self.expert, self.zone = agent, expert, zone
        self.hold, self.lookahead = int(hold), int(lookahead)
        self.hold_on = None if hold_on is None else tuple(int(i) for i in hold_on)
        self.flags: list[bool] = []
        self._left = 0
        self._prev: np.ndarray | None = None
        self._info: dict[str, Any] = {}

    def reset(self, env: gym.Env, rng: np.random.Generator) -> None:
        self.agent.reset(env, rng)
        self.expert.reset(env, rng)
        self.flags = []
        self._left = 0
        self._prev = None

    def see(self, info: dict[str, Any]) -> None:
        self._info = info

    def act(self, obs: np.ndarray, env: gym.Env) -> np.ndarray:
        own = self.agent.act(obs, env)
        info = self._info
        cost = np.asarray(info["cost"], float)
        seen = cost
        if self.lookahead and self._prev is not None:
            seen = cost + self.lookahead * (cost - self._prev)
        self._prev = cost
        defer = ask_expert(seen, bool(info["warmup"]), self.zone, "critical")
        if defer and (self.hold_on is None or self.zone.per_dim(seen[None])[0, self.hold_on].any()):
            self._left = self.hold
        elif not defer and self._left > 0:  # (zone steps of other dimensions pause the count)
            defer, self._left = True, self._left - 1
        self.flags.append(defer)
        return np.asarray(self.expert.act(obs, env), np.float32) if defer else own

    def episode_report(self) -> tuple[dict[str, float], dict[str, np.ndarray]]:
        flags = np.asarray(self.flags, bool)
        n = int(flags.sum())
        return (
            {"deferred_steps": float(n), "deferred_share": n / max(len(flags), 1)},
            {"deferred": flags},
        )


def dimension_indices(names: tuple[str, ...], dims: tuple[str, ...]) -> tuple[int, ...] | None:
    """The indices of safety dimensions ``names`` in ``dims`` (``()``: ``None``, any).

    >>> dimension_indices(("front",), ("left", "front", "right"))
    (1,)
    >>> dimension_indices((), ("left",)) is None
    True
    """
    unknown = [n for n in names if n not in dims]
    if unknown:
        raise ValueError(f"unknown safety dimension(s) {unknown}: the task's are {list(dims)}")
    return tuple(dims.index(n) for n in names) or None


@dataclass(frozen=True)
class DeferralSource:
    """A deferring agent for :func:`safe_bc.distributed.evaluate.evaluate` (pickles cheaply)."""

    agent: Any
    """The agent's source (``NetSource``)."""
    expert: Any
    """The expert's config (:func:`safe_bc.collection.build_expert`)."""
    limits: tuple[float, ...]
    """``d_s`` of the demonstrations."""
    width: float
    """``w``: defer where ``c_s >= d_s - w``."""
    combine: str = "any"
    """How per-dimension flags combine (the selection's)."""
    hold: int = 0
    """Steps the expert keeps acting after the last step in the zone (0: only in the zone)."""
    lookahead: int = 0
    """Steps the cost is extrapolated for the zone test (0: the cost itself)."""
    hold_on: tuple[int, ...] | None = None
    """Dimensions (indices) whose zone test starts the hold (``None``: any)."""

    def build(self) -> DeferringPolicy:
        zone = CriticalZone(self.limits, self.width, self.combine)  # type: ignore[arg-type]
        expert = build_expert(self.expert)
        return DeferringPolicy(
            self.agent.build(), expert, zone, self.hold, self.lookahead, self.hold_on
        )


def handover_source(
    agent: Any, handover: Any, expert: Any, limits: Any, dims: tuple[str, ...]
) -> DeferralSource:
    """``agent`` (a policy source) with ``handover`` (a :class:`safe_bc.handover.HandoverConfig`)
    to ``expert`` (its config) at the limits ``d_s`` of a task with safety dimensions ``dims``."""
    return DeferralSource(
        agent, expert, tuple(float(x) for x in limits), float(handover.width), "any",
        int(handover.hold), int(handover.lookahead), dimension_indices(handover.hold_on, dims),
    )  # fmt: skip
