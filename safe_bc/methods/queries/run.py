"""The rounds of a critical-zone query run (resumable per round, no Ray).

Round ``r`` rolls the current agent (the start, then round ``r - 1``'s) out on
``episodes_per_round`` training tracks, asks the expert where :class:`QueryConfig` says,
writes the labelled states (``round_r/queries.npz``, atomically), retrains BC from scratch on
the demonstrations plus every round's queries so far (queried states join ``T_eps`` in
``"critical"`` mode; ``d_s`` stays the demonstrations'), writes the net
(``round_r/policy``, one checkpoint unit) and then ``round_r/done.json``. A rerun skips the
done rounds, reuses a written ``queries.npz`` and redoes the rest, bit-identically.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from safe_bc.bc.checkpoint import checkpoint_unit, save_checkpoint
from safe_bc.bc.net import BCNet
from safe_bc.data.atomic import write_json_atomic
from safe_bc.data.demos import Demonstrations
from safe_bc.data.provenance import repo_relative
from safe_bc.methods.queries.config import (
    DONE,
    FORMAT,
    IDENTITY,
    POLICY,
    QUERIES,
    QueryConfig,
    round_dir,
    track_seeds,
)
from safe_bc.methods.queries.data import load_round, save_round
from safe_bc.methods.queries.logic import aggregate_selection
from safe_bc.methods.queries.rollout import EpisodeQueries, QueryJob, apply_budget, query_tracks
from safe_bc.methods.rounds import (
    ROUND_CURVE,
    TrainFn,
    TrainJob,
    aggregate_rows,
    check_identity,
    policy_source,
    read_json,
    save_round_net,
    train_local,
    weights_digest,
    with_batches,
)
from safe_bc.rollout.evaluate import NetSource
from safe_bc.run_config import RunConfig
from safe_bc.selection import CriticalZone, Selection

RolloutFn = Callable[[QueryJob, Sequence[int]], list[EpisodeQueries]]
"""Rolls a job out on tracks, results in track order (:func:`query_tracks` in this process;
``safe_bc.distributed.rollouts.ChunkedRayRollouts``; the measurement's process pool)."""


@dataclass(frozen=True)
class QueryResult:
    """Outcome of :func:`run_queries`."""

    folder: Path
    """The run folder (``identity.json``, ``start/``, ``round_r/``)."""
    rounds: list[dict[str, Any]]
    """Each round's ``done.json``: queries, queries per episode, episodes beyond d_s, ..."""
    resumed_rounds: int
    """Rounds found done when the call began."""

    @property
    def policy(self) -> Path:
        """The last round's net (a BC checkpoint, evaluable with ``safe-bc evaluate``)."""
        return self.folder / round_dir(len(self.rounds) - 1) / POLICY

    @property
    def total_queries(self) -> int:
        return int(sum(r["queries"] for r in self.rounds))

    @property
    def total_episodes(self) -> int:
        return int(sum(r["episodes"] for r in self.rounds))


def query_zone(selection: Selection, config: QueryConfig) -> CriticalZone:
    """The query zone: the demonstrations' ``d_s`` with the query eps (default the selection's)."""
    eps = selection.config.eps if config.eps is None else config.eps
    return CriticalZone(tuple(selection.thresholds), eps, selection.config.combine)


@dataclass(frozen=True)
class QueryPlan:
    """What a query run does, decided from its start, run config, inputs and config."""

    config: QueryConfig
    """The query run's settings."""
    base: Selection
    """The demonstrations' own selection (their ``d_s`` is every round's)."""
    retrain: RunConfig
    """Each round's retraining (the start's run config with ``config.batches``)."""
    start: NetSource
    """The first round's agent."""
    identity: dict[str, Any]
    """What a folder resumed must have been started with (``identity.json``)."""
    zone: CriticalZone
    """Where the expert is asked."""
    frame_stack: int
    """Frames the agent sees at once."""
    env_config: Any
    """The environment the rounds roll out in."""
    expert_config: Any
    """The expert asked."""
    demos_path: str
    """The demonstrations, as recorded with every round's net."""


def plan_queries(
    start: BCNet,
    run_config: RunConfig,
    demos: Demonstrations,
    demos_path: str | Path,
    env_config: Any,
    expert_config: Any,
    config: QueryConfig,
) -> QueryPlan:
    """The :class:`QueryPlan` of a query run (nothing is read or written)."""
    from safe_bc.methods.experiment import select_for

    base = select_for(demos, run_config.selection)
    identity = {
        "format": FORMAT,
        "config": config.identity(),
        "run_config": run_config.to_dict(),
        "demos": repo_relative(demos_path),
        "env": str(env_config),
        "expert": str(expert_config),
        "start_weights_sha256": weights_digest(start.state_dict()),
    }
    return QueryPlan(
        config=config,
        base=base,
        retrain=with_batches(run_config, config.batches),
        start=NetSource.from_model(start, run_config.bc),
        identity=identity,
        zone=query_zone(base, config),
        frame_stack=run_config.bc.preprocess.frame_stack,
        env_config=env_config,
        expert_config=expert_config,
        demos_path=str(demos_path),
    )


def run_queries(
    start: BCNet,
    run_config: RunConfig,
    demos: Demonstrations,
    demos_path: str | Path,
    env_config: Any,
    expert_config: Any,
    folder: str | Path,
    config: QueryConfig,
    *,
    rollouts: RolloutFn = query_tracks,
    train: TrainFn = train_local,
    action_bounds: tuple[Any, Any] | None = None,
    on_round: Callable[[dict[str, Any]], None] | None = None,
) -> QueryResult:
    """Run (or resume) the rounds of ``config`` from the trained net ``start`` in ``folder``.

    ``run_config`` is the start's (selection and BC settings; ``config.batches`` overrides the
    batches of each retraining). A folder of another start, run config, demonstrations or
    query config raises ``ValueError``.
    """
    folder = Path(folder)
    plan = plan_queries(start, run_config, demos, demos_path, env_config, expert_config, config)
    check_identity(folder / IDENTITY, plan.identity, "query run", "query config")
    if not (folder / "start" / "config.json").is_file():  # for the record (and inspection)
        with checkpoint_unit(folder / "start") as unit:
            save_checkpoint(unit, start, run_config.bc)
    rounds: list[dict[str, Any]] = []
    episodes: list[EpisodeQueries] = []
    agent: Any = plan.start
    resumed = 0
    for r in range(config.rounds):
        here = folder / round_dir(r)
        done = read_json(here / DONE)
        if done is not None and (here / POLICY / "config.json").is_file():
            rounds.append(done)
            episodes += load_round(here / QUERIES)
            resumed += 1 if resumed == r else 0
            agent = policy_source(here / POLICY)
            continue
        summary, agent = _query_round(
            plan, here, r, agent, demos, episodes, rollouts, train, action_bounds
        )
        write_json_atomic(here / DONE, summary)
        rounds.append(summary)
        if on_round is not None:
            on_round(summary)
    return QueryResult(folder, rounds, resumed)


def _query_round(
    plan: QueryPlan,
    here: Path,
    r: int,
    agent: Any,
    demos: Demonstrations,
    episodes: list[EpisodeQueries],
    rollouts: RolloutFn,
    train: TrainFn,
    action_bounds: tuple[Any, Any] | None,
) -> tuple[dict[str, Any], Any]:
    """Round ``r`` in ``here``: roll ``agent`` out and ask the expert (or read the queries
    written before), retrain on the demonstrations plus every round's queries (``episodes``,
    extended), write the net: ``(the round's summary, its agent)``."""
    config = plan.config
    t0 = time.perf_counter()
    if (here / QUERIES).is_file():
        mine = load_round(here / QUERIES)
    else:
        job = QueryJob(
            plan.env_config,
            agent,
            plan.expert_config,
            plan.zone,
            config.mode,
            plan.frame_stack,
            config.max_steps,
            config.seed,
        )
        seeds = track_seeds(config.seed, r, config.episodes_per_round)
        mine = apply_budget(rollouts(job, seeds), config.query_budget)
        save_round(here / QUERIES, mine)
    t_roll = time.perf_counter() - t0
    episodes.extend(mine)
    data, queried = aggregate_rows(demos, episodes, [e.queried for e in episodes])
    retrain = plan.retrain
    selection = aggregate_selection(
        data.costs, data.scored, queried, retrain.selection, plan.base.thresholds, config.mode
    )
    source = train(TrainJob(data, selection, retrain, action_bounds, curve=here / ROUND_CURVE))
    save_round_net(
        here / POLICY,
        source,
        retrain.bc,
        "queries",
        plan.identity,
        r,
        plan.env_config,
        plan.demos_path,
    )
    return round_summary(r, mine, selection, t_roll, time.perf_counter() - t0), source


def round_summary(
    r: int, mine: list[EpisodeQueries], selection: Selection, t_roll: float, seconds: float
) -> dict[str, Any]:
    """Round ``r``'s ``done.json``: its queries, the episodes beyond ``d_s``, the rows it
    trained on and its seconds."""
    counts = [e.n_queries for e in mine]
    return {
        "round": r,
        "episodes": len(mine),
        "queries": int(sum(counts)),
        "queries_per_episode": float(np.mean(counts)),
        "queries_per_step": float(sum(counts) / max(sum(e.length for e in mine), 1)),
        "episodes_beyond": int(sum(e.beyond_steps > 0 for e in mine)),
        "beyond_steps": int(sum(e.beyond_steps for e in mine)),
        "rollout_reward_mean": float(np.mean([e.reward for e in mine])),
        "train_rows": int(selection.n_valid),
        "critical_rows": int(selection.n_critical),
        "rollout_seconds": t_roll,
        "seconds": seconds,
    }
