"""One training track of a self-imitation round (the agent unperturbed, then once per push,
the kept steps cut out in the worker) and the validation episodes of the keep rule (through
:func:`safe_bc.rollout.evaluate.evaluate_episodes`, the one evaluation path). No Ray: a job's
:meth:`run` is what an actor or this process calls."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from safe_bc.methods.queries.logic import context_rows
from safe_bc.methods.selfimprove.config import KeepUnit, parse_push
from safe_bc.methods.selfimprove.logic import best_runs, kept_steps, push_action, push_allowed
from safe_bc.policy import BatchPolicy, LockstepForward, Policy
from safe_bc.rollout.episode import run_episode


class Push:
    """An :class:`~safe_bc.rollout.episode.ActionPerturbation`: the executed action is the agent's,
    pushed by fixed terms (:func:`~safe_bc.methods.selfimprove.logic.push_action`), except while
    :attr:`allowed` is False (set by :class:`ZoneWatch` from the state's measured cost)."""

    def __init__(self, spec: str, low: np.ndarray, high: np.ndarray) -> None:
        self.terms = parse_push(spec)
        self.low, self.high = np.asarray(low, np.float32), np.asarray(high, np.float32)
        self.allowed = True

    def reset(self, rng: np.random.Generator) -> None:
        self.allowed = True

    def apply(
        self, action: np.ndarray, t: int, rng: np.random.Generator, safety: Any = None
    ) -> np.ndarray:
        if not self.allowed:
            return action
        return push_action(action, self.terms, self.low, self.high)


class HandoverWatch:
    """The agent under the critical-zone handover, pushed only where the agent acts: before
    each action the push is allowed when the state is outside the back-off zone (as
    :class:`ZoneWatch`) and the handover leaves the step to the agent. The expert's steps are
    executed as the expert chose them (their labels are the expert's actions)."""

    def __init__(
        self, deferring: Any, push: Push | None, limits: Sequence[float], eps: float | None
    ) -> None:
        self.deferring, self.push, self.limits, self.eps = deferring, push, np.asarray(limits), eps
        self._allowed = True

    def reset(self, env: gym.Env, rng: np.random.Generator) -> None:
        self.deferring.reset(env, rng)

    def see(self, info: dict[str, Any]) -> None:
        self.deferring.see(info)
        self._allowed = push_allowed(np.asarray(info["cost"]), self.limits, self.eps)

    def act(self, obs: np.ndarray, env: gym.Env) -> np.ndarray:
        action = self.deferring.act(obs, env)
        if self.push is not None:
            self.push.allowed = self._allowed and not self.deferring.flags[-1]
        return action

    @property
    def deferred_steps(self) -> int:
        """Steps of this episode the expert acted."""
        return int(sum(self.deferring.flags))


class ZoneWatch:
    """The agent as a :class:`~safe_bc.rollout.episode.SeesInfo` policy: before each action it tells
    the push whether the state allows one (not in the back-off zone ``c_s >= d_s - eps``;
    ``eps=None``: always)."""

    def __init__(
        self, agent: Policy, push: Push, limits: Sequence[float], eps: float | None
    ) -> None:
        self.agent, self.push, self.limits, self.eps = agent, push, np.asarray(limits), eps

    def reset(self, env: gym.Env, rng: np.random.Generator) -> None:
        self.agent.reset(env, rng)

    def see(self, info: dict[str, Any]) -> None:
        self.push.allowed = push_allowed(np.asarray(info["cost"]), self.limits, self.eps)

    def act(self, obs: np.ndarray, env: gym.Env) -> np.ndarray:
        return self.agent.act(obs, env)


@dataclass(frozen=True)
class KeptPiece:
    """The kept steps of one pushed episode, with the frames their inputs need."""

    seed: int
    """Track (patient) seed."""
    push: int
    """Index of the push in the run's pushes."""
    steps: np.ndarray
    """``(R,) int64`` step index of each row."""
    trained: np.ndarray
    """``(R,) bool``: a kept scored step (else a context row: only stacked)."""
    observations: np.ndarray = field(repr=False)
    """``(R, *obs_shape)``."""
    actions: np.ndarray = field(repr=False)
    """``(R, A) float32`` the executed (pushed) actions: the labels."""
    costs: np.ndarray = field(repr=False)
    """``(R, S) float32`` the rows' costs."""


@dataclass(frozen=True)
class TrackResult:
    """One track of a round: the reference run's outcome, each push's, and the kept pieces."""

    seed: int
    """Track (patient) seed."""
    reference_reward: float
    """Reward of the unperturbed run."""
    reference_beyond: int
    """Scored steps beyond ``d_s`` of the unperturbed run."""
    push_rewards: tuple[float, ...]
    """Reward of each pushed run."""
    push_beyond: tuple[int, ...]
    """Scored steps beyond ``d_s`` of each pushed run."""
    push_kept: tuple[int, ...]
    """Kept (trained) steps of each pushed run."""
    reference_steps: int
    """Env steps of the unperturbed run."""
    push_steps: tuple[int, ...]
    """Env steps of each pushed run."""
    pieces: tuple[KeptPiece, ...]
    """The pushed runs with kept steps, in push order."""
    expert_reward: float = float("nan")
    """Reward of the expert's run on the track (NaN: not run, the bar was the agent's)."""
    push_deferred: tuple[int, ...] = ()
    """Steps of each pushed run the expert acted under the handover (empty: no handover)."""
    expert_steps: int = 0
    """Env steps of the expert's run (0: not run)."""


@dataclass(frozen=True)
class ExploreJob:
    """What a rollout worker needs for the training tracks (pickles cheaply)."""

    env: Any
    """The env's ``EnvConfig``."""
    agent: Any
    """A policy source (``build() -> Policy``)."""
    pushes: tuple[str, ...]
    """Push specs (:func:`~safe_bc.methods.selfimprove.config.parse_push`)."""
    action_bounds: tuple[Any, Any]
    """``(low, high)`` of the action space: pushed actions are clipped to them."""
    limits: tuple[float, ...]
    """``d_s`` of the demonstrations."""
    unit: KeepUnit = "episode"
    """Keep whole episodes or windows (:func:`~safe_bc.methods.selfimprove.logic.kept_steps`)."""
    segment_steps: int = 50
    """Window length for ``unit="segment"``."""
    margin: float = 0.0
    """Kept states have ``c_s <= d_s - margin``."""
    backoff_eps: float | None = None
    """No push where ``c_s >= d_s - backoff_eps``; ``None``: push everywhere."""
    frame_stack: int = 1
    """Context depth of the agent's inputs."""
    max_steps: int | None = None
    """Step cap per episode."""
    rng_seed: int = 0
    """With the track and push, seeds each episode's generator."""
    keep_against: str = "agent"
    """Whose run a pushed run must beat: the agent's unperturbed run or the expert's."""
    keep_best: int | None = None
    """Keep at most this many pushed runs per track, the best by reward (``None``: all)."""
    expert: Any = None
    """The demonstrations' expert config (needed by ``keep_against="expert"`` and
    :attr:`handover`)."""
    handover: Any = None
    """A :class:`safe_bc.handover.HandoverConfig` the runs drive under (``None``: none)."""
    dims: tuple[str, ...] = ()
    """The task's safety dimensions (the handover's ``hold_on`` names them)."""
    lockstep_envs: int = 1
    """Envs the runs are stepped in together (:func:`explore_tracks`); 1: one at a time."""
    forward: LockstepForward = "rows"
    """How the agent's net sees the lockstep runs (:data:`safe_bc.policy.LockstepForward`):
    ``"rows"`` gives the one-env runs bit for bit; ``"batched"`` is faster and may round
    differently."""
    bars: Mapping[int, ExpertRun] | None = None
    """The expert's runs of the tracks, done already (:class:`ExpertRunsJob`, read from the
    runs folder's shared results): with ``keep_against="expert"`` the bar of track ``seed`` is
    ``bars[seed]`` instead of a run of the expert here; ``None``: run here."""

    def run(self, seeds: Sequence[int]) -> list[TrackResult]:
        """Every track in this process: :func:`explore_tracks` over ``lockstep_envs`` envs
        (a net agent), else :func:`explore_track` one track at a time."""
        from safe_bc.rollout.collect import build_expert
        from safe_bc.tasks import make_env

        agent = self.agent.build()
        make_expert = None if self.expert is None else (lambda: build_expert(self.expert))
        n = max(1, min(int(self.lockstep_envs), len(seeds) * max(1, len(self.pushes))))
        envs = [make_env(self.env) for _ in range(n if isinstance(agent, BatchPolicy) else 1)]
        try:
            if isinstance(agent, BatchPolicy):
                return explore_tracks(envs, agent, self, seeds, make_expert)
            expert = None if make_expert is None else make_expert()
            return [explore_track(envs[0], agent, self, s, expert) for s in seeds]
        finally:
            for env in envs:
                env.close()

    def episode_rng(self, seed: int, k: int) -> np.random.Generator:
        """The generator of run ``k`` on track ``seed`` (0: unperturbed, ``1..P``: the pushes,
        ``P + 1``: the expert's own run)."""
        return episode_rng(self.rng_seed, seed, k)

    def expert_runs(self) -> ExpertRunsJob:
        """The job of the expert's own runs (the bars of ``keep_against="expert"``) on this
        job's tracks, alone: what it gives is what :meth:`run` would run for them."""
        return ExpertRunsJob(
            self.env, self.expert, self.rng_seed, len(self.pushes) + 1, self.max_steps
        )

    def driver(self, agent: Policy, expert: Policy | None, push: Push | None) -> Any:
        """The policy a run executes: the agent with the push behind its back-off zone, or,
        under :attr:`handover`, the agent deferring to ``expert`` (:class:`HandoverWatch`)."""
        if self.handover is None:
            if push is None:
                return agent
            return ZoneWatch(agent, push, self.limits, self.backoff_eps)
        from safe_bc.rollout.handover import DeferringPolicy, handover_source

        if expert is None:
            raise ValueError("a self-imitation run under the handover needs the expert's config")
        settings = handover_source(None, self.handover, self.expert, self.limits, self.dims)
        deferring = DeferringPolicy(agent, expert, *settings.policy_args())
        return HandoverWatch(deferring, push, self.limits, self.backoff_eps)


def explore_track(
    env: gym.Env, agent: Policy, job: ExploreJob, seed: int, expert: Policy | None = None
) -> TrackResult:
    """Roll ``agent`` out on track ``seed`` unperturbed, then once per push (under the job's
    handover to ``expert`` where it has one), and ``expert`` alone when the job's bar is the
    expert's run; cut out the kept steps of each pushed run (labels: the executed actions),
    at most ``keep_best`` runs of them. One env, one run at a time: the reference
    :func:`explore_tracks` is bit for bit equal to with ``forward="rows"``."""
    low, high = (np.asarray(b, np.float32) for b in job.action_bounds)
    ref = run_episode(
        env, job.driver(agent, expert, None), seed, job.episode_rng(seed, 0),
        keep_observations=False, max_steps=job.max_steps,
    )  # fmt: skip
    bar = _bar(env, job, seed, ref, expert)
    pushed = []
    for i, spec in enumerate(job.pushes):
        push = Push(spec, low, high)
        driver = job.driver(agent, expert, push)
        ep = run_episode(
            env, driver, seed, job.episode_rng(seed, i + 1), perturbation=push,
            max_steps=job.max_steps,
        )  # fmt: skip
        pushed.append(_pushed_run(job, seed, i, ep, bar[0], driver))
    return _track_result(job, seed, ref, bar, pushed)


def explore_tracks(
    envs: Sequence[gym.Env],
    agent: Any,
    job: ExploreJob,
    seeds: Sequence[int],
    make_expert: Any = None,
) -> list[TrackResult]:
    """:func:`explore_track` of every track, the unperturbed runs and then the pushed runs of
    all ``seeds`` stepped in lockstep over ``envs`` with one ``act_slots`` call per step
    (:func:`safe_bc.methods.selfimprove.lockstep.run_pool`, ``job.forward``); the expert's own runs
    one at a time in ``envs[0]``. Each pushed run's kept rows are cut out as it ends (its
    frames are not held). ``make_expert() -> Policy``: a fresh expert per run (the handover's,
    the bar's)."""
    from safe_bc.methods.selfimprove.lockstep import GivenAction, Run, run_pool

    low, high = (np.asarray(b, np.float32) for b in job.action_bounds)

    def run(seed: int, k: int, push: Push | None) -> Run:
        given = GivenAction()
        expert = None if make_expert is None else make_expert()
        driver = job.driver(given, expert, push)  # type: ignore[arg-type]
        return Run(int(seed), driver, given, job.episode_rng(seed, k), push, push is not None)

    kw = {"max_steps": job.max_steps, "forward": job.forward}
    refs = run_pool(envs, agent, [run(s, 0, None) for s in seeds], **kw)
    expert = None if make_expert is None else make_expert()
    bars = [_bar(envs[0], job, s, ref, expert) for s, ref in zip(seeds, refs, strict=True)]
    runs = [run(s, i + 1, Push(p, low, high)) for s in seeds for i, p in enumerate(job.pushes)]
    pushed: list[Any] = [None] * len(runs)
    n = len(job.pushes)

    def done(j: int, ep: Any) -> None:
        t, i = divmod(j, n)
        pushed[j] = _pushed_run(job, seeds[t], i, ep, bars[t][0], runs[j].driver)

    run_pool(envs, agent, runs, on_done=done, **kw)
    return [
        _track_result(job, s, ref, bar, pushed[t * n : (t + 1) * n])
        for t, (s, ref, bar) in enumerate(zip(seeds, refs, bars, strict=True))
    ]


def _bar(
    env: gym.Env, job: ExploreJob, seed: int, ref: Any, expert: Policy | None
) -> tuple[np.ndarray, float, int]:
    """What a pushed run on track ``seed`` must beat (per-step rewards), the expert's reward
    and env steps there (NaN and 0 when the bar is the agent's unperturbed run ``ref``)."""
    if job.keep_against != "expert":
        return ref.rewards, float("nan"), 0
    if job.bars is not None:
        return job.bars[int(seed)]
    if expert is None:
        raise ValueError("keep_against='expert' needs the expert's config")
    return expert_run(env, expert, seed, job.episode_rng(seed, len(job.pushes) + 1), job.max_steps)


ExpertRun = tuple[np.ndarray, float, int]
"""The expert's own run on a track: its per-step rewards, total reward and env steps."""


def episode_rng(rng_seed: int, seed: int, k: int) -> np.random.Generator:
    """The generator of run ``k`` on track ``seed`` of a run seeded ``rng_seed``
    (:meth:`ExploreJob.episode_rng`)."""
    return np.random.default_rng([rng_seed, int(seed), k])


def expert_run(
    env: gym.Env, expert: Policy, seed: int, rng: np.random.Generator, max_steps: int | None
) -> ExpertRun:
    """``expert`` alone on track ``seed``: the bar a pushed run must beat there."""
    ex = run_episode(env, expert, seed, rng, keep_observations=False, max_steps=max_steps)
    return ex.rewards, ex.total_reward, len(ex.rewards)


@dataclass(frozen=True)
class ExpertRunsJob:
    """The expert's own runs on training tracks (the bars of ``keep_against="expert"``), run
    apart from the agent's (:meth:`ExploreJob.expert_runs`) so that a run can read them where
    another run with the same expert, tracks and settings ran them (pickles cheaply)."""

    env: Any
    """The env's ``EnvConfig``."""
    expert: Any
    """The demonstrations' expert config."""
    rng_seed: int
    """The run's seed (:func:`episode_rng`)."""
    rng_index: int
    """The expert's run's index among a track's runs (the pushes' count plus one)."""
    max_steps: int | None = None
    """Step cap per episode."""

    def run(self, seeds: Sequence[int]) -> list[ExpertRun]:
        """The expert's run on every track, one env and one expert in this process (the
        expert is reset at each episode's start, as in :func:`explore_tracks`)."""
        from safe_bc.rollout.collect import build_expert
        from safe_bc.tasks import make_env

        env, expert = make_env(self.env), build_expert(self.expert)
        try:
            return [
                expert_run(env, expert, s, episode_rng(self.rng_seed, s, self.rng_index),
                           self.max_steps)
                for s in seeds
            ]  # fmt: skip
        finally:
            env.close()


@dataclass(frozen=True)
class _Pushed:
    """One pushed run's outcome and its kept rows (before ``keep_best``)."""

    reward: float
    beyond: int
    steps: int
    deferred: int | None
    piece: KeptPiece | None


def _pushed_run(
    job: ExploreJob, seed: int, i: int, ep: Any, bar: np.ndarray, driver: Any
) -> _Pushed:
    """Push ``i``'s run ``ep`` on track ``seed``: its outcome and, where the keep unit keeps
    steps, those rows with their context (frames copied, so the episode may go)."""
    limits = np.asarray(job.limits, np.float64)
    scored = ~ep.warmup
    keep = kept_steps(
        job.unit, ep.costs, scored, ep.final_cost, ep.rewards, bar, limits, job.margin,
        job.segment_steps,
    )  # fmt: skip
    trained = np.flatnonzero(keep & scored)
    piece = None
    if len(trained):
        rows = context_rows(trained, job.frame_stack)
        piece = KeptPiece(
            seed=int(seed),
            push=i,
            steps=rows,
            trained=np.isin(rows, trained),
            observations=ep.observations[rows].copy(),
            actions=ep.executed_actions[rows].astype(np.float32),
            costs=ep.costs[rows].astype(np.float32),
        )
    deferred = driver.deferred_steps if isinstance(driver, HandoverWatch) else None
    beyond = int((np.any(ep.costs > limits, axis=1) & scored).sum())
    return _Pushed(ep.total_reward, beyond, len(ep.rewards), deferred, piece)


def _track_result(
    job: ExploreJob, seed: int, ref: Any, bar: tuple[np.ndarray, float, int], pushed: list
) -> TrackResult:
    """Track ``seed``'s :class:`TrackResult` from its reference run, bar and pushed runs (at
    most ``keep_best`` of them keep their rows)."""
    limits = np.asarray(job.limits, np.float64)
    rewards = [p.reward for p in pushed]
    chosen = best_runs([p.piece is not None for p in pushed], rewards, job.keep_best)
    pieces = [p.piece for p, c in zip(pushed, chosen, strict=True) if c and p.piece is not None]
    return TrackResult(
        seed=int(seed),
        reference_reward=ref.total_reward,
        reference_beyond=int((np.any(ref.costs > limits, axis=1) & ~ref.warmup).sum()),
        push_rewards=tuple(rewards),
        push_beyond=tuple(p.beyond for p in pushed),
        push_kept=tuple(
            int(p.piece.trained.sum()) if c and p.piece is not None else 0
            for p, c in zip(pushed, chosen, strict=True)
        ),
        reference_steps=len(ref.rewards),
        push_steps=tuple(p.steps for p in pushed),
        pieces=tuple(pieces),
        expert_reward=bar[1],
        push_deferred=tuple(p.deferred for p in pushed if p.deferred is not None),
        expert_steps=bar[2],
    )


@dataclass(frozen=True)
class ValidateJob:
    """The keep rule's validation episodes of one agent (pickles cheaply)."""

    env: Any
    """The env's ``EnvConfig``."""
    agent: Any
    """A policy source (``build() -> Policy``)."""
    limits: tuple[float, ...]
    """``d_s`` of the demonstrations."""
    eps: float
    """The selection's eps (for the evaluation's ``critical_share``)."""
    combine: str = "any"
    """The selection's combine."""
    max_steps: int | None = None
    """Step cap per episode."""
    lockstep_envs: int = 1
    """Envs the validation episodes are stepped in together (a net agent)."""
    forward: LockstepForward = "rows"
    """The evaluation's ``lockstep_forward`` (``"rows"``: the one-env episodes bit for bit)."""

    def run(self, seeds: Sequence[int]) -> list[dict[str, float]]:
        """The evaluation's metrics of every validation track
        (:func:`safe_bc.rollout.evaluate.evaluate_episodes`, ``lockstep_envs`` at a time)."""
        from safe_bc.rollout.evaluate import evaluate_episodes
        from safe_bc.tasks import make_env

        envs = [make_env(self.env) for _ in range(max(1, min(self.lockstep_envs, len(seeds))))]
        try:
            rows = evaluate_episodes(
                envs, self.agent.build(), seeds, thresholds=np.asarray(self.limits),
                eps=self.eps, max_steps=self.max_steps, combine=self.combine,  # type: ignore[arg-type]
                lockstep_forward=self.forward,
            )  # fmt: skip
        finally:
            for env in envs:
                env.close()
        return [metrics for metrics, _ in rows]


def local_rollouts(
    job: ExploreJob | ValidateJob | ExpertRunsJob, seeds: Sequence[int]
) -> list[Any]:
    """A job's tracks in this process (``job.run``) with one torch thread (restored after), as
    in a Ray actor, so the policy's forward passes are the same wherever the tracks run
    (``safe_bc.distributed.rollouts.ChunkedRayRollouts`` calls this in its actors); a
    process's default threads also spin against each other when rollouts run side by side
    (2 such processes on 2 cores ran ~6x slower per step)."""
    import torch

    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return job.run(seeds)
    finally:
        torch.set_num_threads(previous)
