"""The handover at use time (what a recommender does with its agent): the agent acts, except
where the measured cost is within a width ``w`` of ``d_s`` (or a restart rule fires), where the
expert acts ("ask the clinician"). One job: the wrapper; its settings are
:class:`safe_bc.handover.HandoverConfig`."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from safe_bc.policy import BatchPolicy, Policy
from safe_bc.rollout.collect import build_expert
from safe_bc.selection import CriticalZone


@dataclass
class HandoverState:
    """One episode's handover: the previous cost, the hold steps left, the per-step flags."""

    prev: np.ndarray | None = None
    left: int = 0
    flags: list[bool] = field(default_factory=list)
    seen: np.ndarray | None = None
    """The previous step's cost (with a stall restart)."""
    still: int = 0
    """Steps in a row with that cost."""
    restart: int = 0
    """Steps the expert still acts after a stall."""
    slow: int = 0
    """Steps in a row below the pace (with a pace rule)."""
    rush: int = 0
    """Steps the expert still acts after the car fell below the pace."""


def stall_decision(
    state: HandoverState, cost: Any, warmup: bool, stall: int, stall_hold: int
) -> bool:
    """Whether the expert acts for a stalled agent (updating ``state``): after ``stall`` steps
    in a row with the same cost in every dimension (a car standing still) outside warm-up,
    for ``stall_hold`` steps.

    >>> s = HandoverState()
    >>> [stall_decision(s, c, False, 2, 2) for c in ([1, 2], [1, 2], [1, 2], [1, 3], [1, 4])]
    [False, False, True, True, False]
    """
    cost = np.asarray(cost, float)
    same = state.seen is not None and np.array_equal(cost, state.seen)
    state.seen, state.still = cost.copy(), (state.still + 1 if same else 0)
    if not warmup and state.still >= stall:
        state.restart, state.still = stall_hold, 0
    if state.restart > 0:
        state.restart -= 1
        return True
    return False


def pace_decision(
    state: HandoverState, speed: float, warmup: bool, pace: float, steps: int, hold: int
) -> bool:
    """Whether the expert acts for an agent falling behind (updating ``state``): after
    ``steps`` steps in a row with ``speed`` below ``pace`` outside warm-up, for ``hold`` steps
    (the count starts again after them).

    >>> s = HandoverState()
    >>> [pace_decision(s, v, False, 30.0, 2, 2) for v in (40, 20, 20, 50, 50, 50, 20)]
    [False, False, True, True, False, False, False]
    >>> s = HandoverState()
    >>> [pace_decision(s, v, w, 30.0, 2, 2) for v, w in ((5, True), (5, True), (5, False))]
    [False, False, False]
    """
    state.slow = state.slow + 1 if (not warmup and speed < pace) else 0
    if state.slow >= steps:
        state.rush, state.slow = hold, 0
    if state.rush > 0:
        state.rush -= 1
        return True
    return False


def car_speed(env: gym.Env) -> float:
    """The car's speed (the hull's linear velocity's norm, privileged simulator state, as the
    scripted expert reads it) in CarRacing ``env``."""
    car = getattr(env.unwrapped, "car", None)
    if car is None:
        raise ValueError("a handover pace needs a car: the env has none (CarRacing only)")
    v = car.hull.linearVelocity
    return float(np.hypot(v[0], v[1]))


def handover_decision(
    state: HandoverState,
    info: dict[str, Any],
    zone: CriticalZone,
    hold: int,
    lookahead: int,
    hold_on: tuple[int, ...] | None,
) -> bool:
    """Whether the expert acts in the state whose ``info`` this is (updating ``state``): the
    zone test on the cost (extrapolated ``lookahead`` steps at its last change), the hold
    started by a zone step of the ``hold_on`` dimensions, never in warm-up."""
    cost = np.asarray(info["cost"], float)
    seen = cost
    if lookahead and state.prev is not None:
        seen = cost + lookahead * (cost - state.prev)
    state.prev = cost
    warmup = bool(info["warmup"])
    defer = False if warmup else bool(zone.critical(np.asarray(seen, np.float64)[None])[0])
    if defer and (hold_on is None or zone.per_dim(seen[None])[0, hold_on].any()):
        state.left = hold
    elif not defer and state.left > 0:  # (zone steps of other dimensions pause the count)
        defer, state.left = True, state.left - 1
    state.flags.append(defer)
    return defer


def handover_report(state: HandoverState) -> tuple[dict[str, float], dict[str, np.ndarray]]:
    """An episode's ``deferred_steps``, ``deferred_share`` and per-step ``deferred`` flags."""
    flags = np.asarray(state.flags, bool)
    n = int(flags.sum())
    return (
        {"deferred_steps": float(n), "deferred_share": n / max(len(flags), 1)},
        {"deferred": flags},
    )


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
    (:class:`safe_bc.rollout.evaluate.ReportsSteps`)."""

    def __init__(
        self,
        agent: Policy,
        expert: Policy,
        zone: CriticalZone,
        hold: int = 0,
        lookahead: int = 0,
        hold_on: tuple[int, ...] | None = None,
        safer: tuple[int, ...] | None = None,
        safest: bool = False,
        stall: tuple[int, int] = (0, 0),
        pace: tuple[float, int, int] = (0.0, 0, 0),
    ) -> None:
        if hold < 0 or lookahead < 0:
            raise ValueError(f"hold and lookahead must be >= 0 steps, got {hold}, {lookahead}")
        dims = len(zone.limits)
        if hold_on is not None and not all(0 <= int(i) < dims for i in hold_on):
            raise ValueError(f"hold_on must be dimension indices in [0, {dims}), got {hold_on}")
        self.agent, self.expert, self.zone = agent, expert, zone
        self.hold, self.lookahead = int(hold), int(lookahead)
        self.hold_on = None if hold_on is None else tuple(int(i) for i in hold_on)
        self.safer = None if safer is None else np.asarray(safer, np.float32)
        if safest and self.safer is None:
            raise ValueError("the safest action needs the task's safer direction (safer=)")
        self.safest = bool(safest)
        self.stall = (int(stall[0]), int(stall[1]))
        self.pace = (float(pace[0]), int(pace[1]), int(pace[2]))
        self.state = HandoverState()
        self._info: dict[str, Any] = {}

    @property
    def flags(self) -> list[bool]:
        """This episode's per-step flags so far (True: the expert acted)."""
        return self.state.flags

    def reset(self, env: gym.Env, rng: np.random.Generator) -> None:
        self.agent.reset(env, rng)
        self.expert.reset(env, rng)
        self.state = HandoverState()

    def see(self, info: dict[str, Any]) -> None:
        self._info = info

    def act(self, obs: np.ndarray, env: gym.Env) -> np.ndarray:
        own = self.agent.act(obs, env)
        defer = self._decide(self.state, self._info, env)
        return self._fallback(own, obs, env, self.expert) if defer else own

    def _fallback(self, own: Any, obs: np.ndarray, env: gym.Env, expert: Policy) -> np.ndarray:
        """The action in the zone: the expert's; (``safer`` set: the cap) the agent's, each
        component no further than the expert's against the safer direction; or (``safest``)
        each component at the action space's bound in the safer direction (the expert is not
        consulted)."""
        if self.safest:
            return safest_action(env.action_space, self.safer)
        action = np.asarray(expert.act(obs, env), np.float32)
        if self.safer is None:
            return action
        return cap_action(np.asarray(own, np.float32), action, self.safer)

    def _decide(self, state: HandoverState, info: dict[str, Any], env: gym.Env | None) -> bool:
        defer = handover_decision(state, info, self.zone, self.hold, self.lookahead, self.hold_on)
        if self.stall[0] and stall_decision(state, info["cost"], bool(info["warmup"]), *self.stall):
            defer = state.flags[-1] = True
        if self.pace[0] and pace_decision(
            state,
            car_speed(env),
            bool(info["warmup"]),
            *self.pace,  # type: ignore[arg-type]
        ):
            defer = state.flags[-1] = True
        return defer

    def episode_report(self) -> tuple[dict[str, float], dict[str, np.ndarray]]:
        return handover_report(self.state)


class LockstepDeferringPolicy(DeferringPolicy):
    """:class:`DeferringPolicy` over envs stepped in lockstep (a
    :class:`~safe_bc.policy.BatchPolicy`): the agent acts for every running env with one
    ``act_slots`` call, the zone test, hold and expert run per env. With ``forward="rows"``
    every episode is, bit for bit, the one-env path's (the same per-env computations); with
    ``"batched"`` the agent's actions may round differently
    (:data:`safe_bc.policy.LockstepForward`). Each env's expert is its own (``make_expert``),
    reset with the episode's seed as the one-env evaluation does."""

    def __init__(
        self,
        agent: Any,
        make_expert: Callable[[], Policy],
        zone: CriticalZone,
        hold: int = 0,
        lookahead: int = 0,
        hold_on: tuple[int, ...] | None = None,
        safer: tuple[int, ...] | None = None,
        safest: bool = False,
        stall: tuple[int, int] = (0, 0),
        pace: tuple[float, int, int] = (0.0, 0, 0),
    ) -> None:
        super().__init__(
            agent, make_expert(), zone, hold, lookahead, hold_on, safer, safest, stall, pace
        )
        self.make_expert = make_expert
        self._envs: list[gym.Env] = []
        self._experts: list[Policy] = []
        self._states: list[HandoverState] = []
        self._infos: dict[int, dict[str, Any]] = {}

    def reset_slots(self, n: int) -> None:
        self.agent.reset_slots(n)
        self._states = [HandoverState() for _ in range(n)]
        self._experts = [self.make_expert() for _ in range(n)]
        self._infos = {}

    def start_slots(self, envs: Sequence[gym.Env], seeds: Sequence[int]) -> None:
        """The envs of the slots (after their reset) and their seeds: each slot's expert is
        reset with ``np.random.default_rng(seed)``, as :func:`evaluate_episode` resets a policy."""
        self._envs = list(envs)
        for expert, env, seed in zip(self._experts, envs, seeds, strict=True):
            expert.reset(env, np.random.default_rng(seed))

    def see_slots(self, infos: Sequence[dict[str, Any]], slots: np.ndarray) -> None:
        """The ``info`` of each running slot's current state."""
        self._infos = {int(s): info for s, info in zip(slots, infos, strict=True)}

    def act_slots(self, obs: np.ndarray, slots: np.ndarray, forward: Any = "rows") -> np.ndarray:
        actions = np.array(self.agent.act_slots(obs, slots, forward), np.float32)
        for i, s in enumerate(int(x) for x in slots):
            if self._decide(self._states[s], self._infos[s], self._envs[s] if self._envs else None):
                actions[i] = self._fallback(actions[i], obs[i], self._envs[s], self._experts[s])
        return actions

    def slot_report(self, slot: int) -> tuple[dict[str, float], dict[str, np.ndarray]]:
        """Slot ``slot``'s :meth:`episode_report`."""
        return handover_report(self._states[slot])


def cap_action(own: np.ndarray, expert: np.ndarray, safer: np.ndarray) -> np.ndarray:
    """The agent's action ``own`` capped by the expert's: per component, the one further in the
    safer direction (``safer``: -1 where a lower value is safer, +1 where a higher one is).

    >>> cap_action(np.array([0.5, -0.5]), np.array([0.2, 0.0]), np.array([-1, -1])).tolist()
    [0.20000000298023224, -0.5]
    """
    return np.where(safer < 0, np.minimum(own, expert), np.maximum(own, expert)).astype(np.float32)


def safest_action(space: Any, safer: np.ndarray) -> np.ndarray:
    """The action of the box ``space`` furthest in the safer direction: per component its
    lower bound where ``safer`` is -1, its upper bound where it is +1.

    >>> from gymnasium.spaces import Box
    >>> safest_action(Box(-1.0, 1.0, (2,)), np.array([-1, 1])).tolist()
    [-1.0, 1.0]
    """
    return np.where(safer < 0, space.low, space.high).astype(np.float32)


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
    """The expert's config (:func:`safe_bc.rollout.collect.build_expert`)."""
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
    widths: tuple[float, ...] | None = None
    """The zone's width per dimension (``None``: ``width`` in every one)."""
    safer: tuple[int, ...] | None = None
    """The task's safer direction per action component for a capping handover (``None``: the
    expert's action replaces the agent's)."""
    safest: bool = False
    """The zone's action is the safest one (:func:`safest_action`; needs ``safer``)."""
    stall: tuple[int, int] = (0, 0)
    """``(still steps, expert steps)`` of the stall restart (:func:`stall_decision`; 0: off)."""
    pace: tuple[float, int, int] = (0.0, 0, 0)
    """``(speed, steps below it, expert steps)`` of the pace rule (:func:`pace_decision`; 0:
    off)."""

    def build(self) -> DeferringPolicy:
        """The deferring policy; a :class:`LockstepDeferringPolicy` when the agent acts for
        envs in lockstep (a BC net), so the evaluation steps several envs at once."""
        agent = self.agent.build()
        args = self.policy_args()
        if isinstance(agent, BatchPolicy):
            return LockstepDeferringPolicy(agent, lambda: build_expert(self.expert), *args)
        return DeferringPolicy(agent, build_expert(self.expert), *args)

    def policy_args(
        self,
    ) -> tuple[
        CriticalZone, int, int, tuple[int, ...] | None, Any, bool, tuple[int, int],
        tuple[float, int, int],
    ]:  # fmt: skip
        """The zone, hold, lookahead, hold dimensions, safer direction, safest switch, stall
        restart and pace rule a :class:`DeferringPolicy` takes after its agent and expert."""
        zone = CriticalZone(self.limits, self.width, self.combine)  # type: ignore[arg-type]
        if self.widths is not None:  # c >= d - w per dimension: the zone at d - w, width 0
            shifted = tuple(d - w for d, w in zip(self.limits, self.widths, strict=True))
            zone = CriticalZone(shifted, 0.0, self.combine)  # type: ignore[arg-type]
        return (
            zone, self.hold, self.lookahead, self.hold_on, self.safer, self.safest, self.stall,
            self.pace,
        )  # fmt: skip


def handover_source(
    agent: Any, handover: Any, expert: Any, limits: Any, dims: tuple[str, ...]
) -> DeferralSource:
    """``agent`` (a policy source) with ``handover`` (a :class:`safe_bc.handover.HandoverConfig`)
    to ``expert`` (its config) at the limits ``d_s`` of a task with safety dimensions ``dims``;
    a capping or safest-action handover takes the expert's task's safer direction (refused where
    it has none)."""
    from safe_bc.tasks.registry import spec_of_expert

    safer = None
    if handover.fallback in ("cap", "safest"):
        task = spec_of_expert(type(expert))
        if task.safer_actions is None:
            raise ValueError(
                f"a {handover.fallback!r} handover needs a safer direction: {task.name!r} has none"
            )
        safer = tuple(task.safer_actions)
    widths = handover.width_per_dim(dims) if handover.widths else None
    return DeferralSource(
        agent, expert, tuple(float(x) for x in limits), float(handover.width), "any",
        int(handover.hold), int(handover.lookahead), dimension_indices(handover.hold_on, dims),
        widths, safer, handover.fallback == "safest",
        (int(handover.stall), int(handover.stall_hold)),
        (float(handover.pace), int(handover.pace_steps), int(handover.pace_hold)),
    )  # fmt: skip
