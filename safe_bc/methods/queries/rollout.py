"""One episode of the agent with the expert asked where the zone says (no Ray): the agent's
action is executed everywhere; the expert's action is recorded at the asked states, at the
visited state itself (the privileged CarRacing expert reads ``env.unwrapped``)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from safe_bc.methods.queries.config import QueryMode
from safe_bc.methods.queries.logic import ask_expert, budget_keep, context_rows
from safe_bc.policy import Policy
from safe_bc.rollout.collect import build_expert
from safe_bc.rollout.episode import run_episode
from safe_bc.selection import CriticalZone


class AskingPolicy:
    """A :class:`~safe_bc.policy.Policy` (and :class:`~safe_bc.rollout.episode.SeesInfo`): the agent
    acts; the expert is asked, and its answer recorded, in states where :func:`ask_expert`
    says so. The expert is called only there (every call is a query)."""

    def __init__(self, agent: Policy, expert: Policy, zone: CriticalZone, mode: QueryMode) -> None:
        self.agent, self.expert, self.zone, self.mode = agent, expert, zone, mode
        self.labels: dict[int, np.ndarray] = {}
        self._t = 0
        self._info: dict[str, Any] = {}

    def reset(self, env: gym.Env, rng: np.random.Generator) -> None:
        self.agent.reset(env, rng)
        self.expert.reset(env, rng)
        self.labels, self._t = {}, 0

    def see(self, info: dict[str, Any]) -> None:
        self._info = info

    def act(self, obs: np.ndarray, env: gym.Env) -> np.ndarray:
        action = self.agent.act(obs, env)
        info = self._info
        if ask_expert(np.asarray(info["cost"]), bool(info["warmup"]), self.zone, self.mode):
            self.labels[self._t] = np.asarray(self.expert.act(obs, env), np.float32)
        self._t += 1
        return action


@dataclass(frozen=True)
class EpisodeQueries:
    """The labelled states of one rollout episode, with the frames their inputs need.

    Rows are the queried steps and, with frame stacking, the steps before them (context rows,
    not queried: never trained on, only stacked).
    """

    seed: int
    """Track (patient) seed."""
    length: int
    """Steps the episode ran."""
    reward: float
    """The agent's episode reward."""
    beyond_steps: int
    """Scored steps beyond ``d_s`` in some dimension."""
    steps: np.ndarray
    """``(R,) int64`` step index of each row."""
    queried: np.ndarray
    """``(R,) bool``: the row was queried (else a context row)."""
    observations: np.ndarray = field(repr=False)
    """``(R, *obs_shape)``."""
    actions: np.ndarray = field(repr=False)
    """``(R, A) float32``: the expert's label on queried rows, the agent's action elsewhere."""
    costs: np.ndarray = field(repr=False)
    """``(R, S) float32`` the rows' costs."""
    frame_stack: int = 1
    """Context depth the rows were cut with (the agent's frame stack)."""

    @property
    def n_queries(self) -> int:
        return int(self.queried.sum())

    def keep_first(self, n: int) -> EpisodeQueries:
        """Only the first ``n`` queries (and their context rows)."""
        if n >= self.n_queries:
            return self
        kept_steps = self.steps[self.queried][:n]
        rows = np.isin(self.steps, context_rows(kept_steps, self.frame_stack))
        queried = self.queried & np.isin(self.steps, kept_steps)
        return EpisodeQueries(
            self.seed,
            self.length,
            self.reward,
            self.beyond_steps,
            self.steps[rows],
            queried[rows],
            self.observations[rows],
            self.actions[rows],
            self.costs[rows],
            self.frame_stack,
        )


@dataclass(frozen=True)
class QueryJob:
    """What a rollout worker needs (pickles cheaply: the agent as a ``NetSource``)."""

    env: Any
    """The env's ``EnvConfig``."""
    agent: Any
    """A policy source (``build() -> Policy``)."""
    expert: Any
    """The expert's config (:func:`safe_bc.rollout.collect.build_expert`)."""
    zone: CriticalZone
    """The query zone (``d_s`` of the demonstrations, the query eps)."""
    mode: QueryMode
    """``"critical"`` or ``"full"``."""
    frame_stack: int = 1
    """Context depth of the agent's inputs."""
    max_steps: int | None = None
    """Step cap per episode."""
    rng_seed: int = 0
    """Seeds each episode's generator with the track (:func:`safe_bc.seeds.episode_rng`)."""


def query_episode(
    env: gym.Env, agent: Policy, expert: Policy, job: QueryJob, seed: int
) -> EpisodeQueries:
    """Roll the agent out on track ``seed`` asking the expert as ``job`` says."""
    asking = AskingPolicy(agent, expert, job.zone, job.mode)
    rng = np.random.default_rng([job.rng_seed, int(seed), 7])
    ep = run_episode(env, asking, seed, rng, keep_observations=True, max_steps=job.max_steps)
    q_steps = np.asarray(sorted(asking.labels), np.int64)
    rows = context_rows(q_steps, job.frame_stack)
    queried = np.isin(rows, q_steps)
    actions = ep.actions[rows].astype(np.float32, copy=True)
    for i, s in enumerate(rows):
        if queried[i]:
            actions[i] = asking.labels[int(s)]
    scored = ~ep.warmup
    beyond = (ep.costs > np.asarray(job.zone.limits, np.float32)).any(axis=1) & scored
    return EpisodeQueries(
        seed=int(seed),
        length=len(ep),
        reward=ep.total_reward,
        beyond_steps=int(beyond.sum()),
        steps=rows,
        queried=queried,
        observations=ep.observations[rows].copy(),
        actions=actions,
        costs=ep.costs[rows].astype(np.float32),
        frame_stack=job.frame_stack,
    )


def query_tracks(job: QueryJob, seeds: Sequence[int]) -> list[EpisodeQueries]:
    """:func:`query_episode` of every track in this process (one env, one agent, one
    expert); the same episodes whichever process runs them."""
    from safe_bc.tasks import make_env

    env = make_env(job.env)
    try:
        agent, expert = job.agent.build(), build_expert(job.expert)
        return [query_episode(env, agent, expert, job, s) for s in seeds]
    finally:
        env.close()


def apply_budget(episodes: Sequence[EpisodeQueries], budget: int | None) -> list[EpisodeQueries]:
    """The round's episodes (in track order) with at most ``budget`` queries in all: the
    first ones (:func:`~safe_bc.methods.queries.logic.budget_keep`)."""
    keep = budget_keep([e.n_queries for e in episodes], budget)
    return [e.keep_first(k) for e, k in zip(episodes, keep, strict=True)]
