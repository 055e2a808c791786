"""The rounds of a self-imitation run (resumable per round, no Ray).

Round ``r`` rolls the current agent (the start, then the last accepted round's) out on
``tracks_per_round`` training tracks, unperturbed and once per push, keeps the pushed steps
that stay inside ``d_s - margin`` and beat the unperturbed run
(:func:`~safe_bc.methods.selfimprove.logic.kept_steps`), writes them (``round_r/kept.npz``,
atomically; with ``frames_on_disk`` their frames go to the run's append-only kept-frame
store instead, :mod:`~safe_bc.methods.selfimprove.store`), retrains BC from scratch on the
demonstrations plus the kept rows of every accepted round and this one (labels: the
executed actions; ``d_s`` and ``T_eps`` stay the demonstrations' unless ``kept_in`` says
otherwise), writes the net (``round_r/policy``, one checkpoint unit), validates it and applies
the keep rule (:func:`~safe_bc.methods.selfimprove.logic.accept_round`) and then writes
``round_r/done.json``. A rejected round's agent and kept rows are dropped: the next round
starts from the previous agent. A rerun skips the done rounds, reuses a written ``kept.npz``
and redoes the rest, bit-identically. The run's curve (``curve.parquet``, TensorBoard event
files beside it) is rewritten after every round.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from safe_bc.bc.checkpoint import checkpoint_unit, save_checkpoint
from safe_bc.bc.net import BCNet
from safe_bc.data.atomic import write_json_atomic
from safe_bc.data.curves import write_curve
from safe_bc.data.demos import Demonstrations
from safe_bc.data.provenance import repo_relative
from safe_bc.methods.improve.config import VALIDATION_SEED_BASE
from safe_bc.methods.queries.config import track_seeds
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
from safe_bc.methods.selfimprove.config import (
    CURVE,
    DONE,
    FORMAT,
    IDENTITY,
    KEPT,
    POLICY,
    START_VALIDATION,
    SelfImproveConfig,
    round_dir,
)
from safe_bc.methods.selfimprove.data import (
    frameless,
    holds_frames,
    load_round,
    round_frames,
    save_round,
)
from safe_bc.methods.selfimprove.logic import accept_round, kept_selection
from safe_bc.methods.selfimprove.rollout import (
    ExpertRun,
    ExpertRunsJob,
    ExploreJob,
    KeptPiece,
    TrackResult,
    ValidateJob,
    local_rollouts,
)
from safe_bc.methods.selfimprove.shared import (
    SHARED_FORMAT,
    SharedResults,
    expert_run_from_json,
    expert_run_to_json,
)
from safe_bc.methods.selfimprove.store import ConcatFrames, KeptFrameStore
from safe_bc.rollout.evaluate import NetSource
from safe_bc.run_config import RunConfig
from safe_bc.selection import Selection

_log = logging.getLogger(__name__)

RolloutFn = Callable[[Any, Sequence[int]], list[Any]]
"""Runs a job (:class:`ExploreJob` or :class:`ValidateJob`) on tracks, results in track order
(:func:`local_rollouts` in this process; ``safe_bc.distributed.rollouts.ChunkedRayRollouts``)."""


@dataclass(frozen=True)
class SelfImproveResult:
    """Outcome of :func:`run_selfimprove`."""

    folder: Path
    """The run folder (``identity.json``, ``start/``, ``round_r/``)."""
    rounds: list[dict[str, Any]]
    """Each round's ``done.json``: kept steps, crossings, validation, accepted, ..."""
    resumed_rounds: int
    """Rounds found done when the call began."""
    agent: str
    """Folder (in :attr:`folder`) of the agent the run ends with: ``"start"`` or the last
    accepted round's."""
    start_validation: dict[str, Any]
    """The start's validation (``start_validation.json``): reward, episodes beyond ``d_s``,
    env steps, seconds."""

    @property
    def policy(self) -> Path:
        """The final agent's net (a BC checkpoint, evaluable with ``safe-bc evaluate``)."""
        return self.folder / "start" if self.agent == "start" else self.folder / self.agent / POLICY

    @property
    def accepted_rounds(self) -> int:
        return int(sum(bool(r["accepted"]) for r in self.rounds))

    @property
    def kept_steps(self) -> int:
        return int(sum(r["kept_steps"] for r in self.rounds))

    @property
    def env_steps(self) -> int:
        """Env steps of the training rollouts (unperturbed and pushed runs of every round;
        validation not included, as in the PPO-Lagrangian's ``env_steps``)."""
        return int(sum(r["env_steps"] for r in self.rounds))

    @property
    def validation_env_steps(self) -> int:
        """Env steps of the keep rule's validation episodes (the start's and every round's)."""
        start = int(self.start_validation["validation_env_steps"])
        return start + int(sum(r["validation_env_steps"] for r in self.rounds))

    @property
    def seconds(self) -> float:
        """Wall time of the run: the start's validation and every round."""
        start = float(self.start_validation["seconds"])
        return start + float(sum(r["seconds"] for r in self.rounds))

    def history(self) -> list[dict[str, Any]]:
        """The learning curve, one row per round after a row for the start (``iteration``
        0), in the PPO-Lagrangian history's column names where they mean the same:
        ``env_steps`` (training rollouts so far), ``val_env_steps`` (this row's validation
        steps), ``train_reward`` and ``train_violation_steps`` (means over the round's pushed
        runs), ``val_reward`` and ``val_any_violation`` (the row's agent on the validation
        tracks, accepted or not), ``seconds`` (this row's wall time); and ``accepted``,
        ``kept_steps``."""
        start = self.start_validation
        n_val = int(start["validation_episodes"])
        rows = [
            {
                "iteration": 0,
                "env_steps": 0,
                "val_env_steps": int(start["validation_env_steps"]),
                "train_reward": float("nan"),
                "train_violation_steps": float("nan"),
                "val_reward": float(start["validation_reward"]),
                "val_any_violation": start["validation_beyond"] / n_val,
                "accepted": True,
                "kept_steps": 0,
                "seconds": float(start["seconds"]),
            }
        ]
        steps = 0
        for r in self.rounds:
            steps += int(r["env_steps"])
            rows.append(
                {
                    "iteration": int(r["round"]) + 1,
                    "env_steps": steps,
                    "val_env_steps": int(r["validation_env_steps"]),
                    "train_reward": float(r["pushed_reward_mean"]),
                    "train_violation_steps": float(r["pushed_violation_steps_mean"]),
                    "val_reward": float(r["validation_reward"]),
                    "val_any_violation": r["validation_beyond"] / n_val,
                    "accepted": bool(r["accepted"]),
                    "kept_steps": int(r["kept_steps"]),
                    "seconds": float(r["seconds"]),
                }
            )
        return rows


def _expert_side(
    config: SelfImproveConfig, demos_path: str | Path, env_config: Any
) -> tuple[Any, Any, tuple[str, ...]]:
    """The explore job's expert config, handover and safety dimensions: the demonstrations'
    expert where the keep rule's bar or the handover needs it, else nothing."""
    if config.keep_against != "expert" and config.handover is None:
        return None, None, ()
    from safe_bc.rollout.collect import stored_expert_config
    from safe_bc.tasks import task_defaults, task_of

    dims = tuple(task_defaults(task_of(env_config.env_id)).safety_dims)
    return stored_expert_config(Path(demos_path)), config.handover, dims


def round_summary(
    r: int,
    tracks: Sequence[TrackResult],
    mine: Sequence[KeptPiece],
    selection: Any,
    config: SelfImproveConfig,
) -> tuple[dict[str, Any], dict[str, Any]]:
    """What round ``r``'s rollouts and training data were (its ``done.json`` before the
    validation), and the values of the options it ran with (the expert's mean reward where
    it was the bar, the pushed runs' deferred share under a handover)."""
    pushed = np.asarray([t.push_beyond for t in tracks])
    steps = sum(t.reference_steps + sum(t.push_steps) + t.expert_steps for t in tracks)
    rollout = {
        "round": r,
        "tracks": len(tracks),
        "pushed_episodes": int(pushed.size),
        "pushed_episodes_beyond": int((pushed > 0).sum()),
        "reference_episodes_beyond": int(sum(t.reference_beyond > 0 for t in tracks)),
        "reference_reward_mean": float(np.mean([t.reference_reward for t in tracks])),
        "pushed_reward_mean": float(np.mean([t.push_rewards for t in tracks])),
        "pushed_violation_steps_mean": float(pushed.mean()),
        "env_steps": int(steps),
        "kept_pieces": len(mine),
        "kept_steps": int(sum(int(p.trained.sum()) for p in mine)),
        "train_rows": int(selection.n_valid),
        "critical_rows": int(selection.n_critical),
    }
    extras: dict[str, Any] = {}
    if config.keep_against == "expert":
        extras["expert_reward_mean"] = float(np.mean([t.expert_reward for t in tracks]))
    if config.handover is not None:
        pushed_steps = sum(sum(t.push_steps) for t in tracks)
        deferred = sum(sum(t.push_deferred) for t in tracks)
        extras["pushed_deferred_share"] = float(deferred / max(pushed_steps, 1))
    return rollout, extras


def validation_seeds(n: int) -> list[int]:
    """The keep rule's validation tracks: the improvement stage's (``VALIDATION_SEED_BASE - k``),
    disjoint from training and held-out evaluation tracks."""
    return [VALIDATION_SEED_BASE - k for k in range(n)]


@dataclass(frozen=True)
class SelfImprovePlan:
    """What a self-imitation run does, decided from its start, run config, inputs and config
    (:func:`plan_selfimprove`; nothing is read or written)."""

    config: SelfImproveConfig
    """The run's settings, resolved."""
    pushes: tuple[Any, ...]
    """The pushes every track is rolled out with."""
    base: Selection
    """The demonstrations' own selection."""
    limits: tuple[float, ...]
    """``d_s``: the demonstrations' thresholds."""
    retrain: RunConfig
    """Each round's retraining (the start's run config, ``config.batches``, ``config.alpha``)."""
    selection: Any
    """The start's selection settings (eps and how costs combine, for the validation)."""
    start: NetSource
    """The first round's agent."""
    identity: dict[str, Any]
    """What a folder resumed must have been started with (``identity.json``)."""
    validation_seeds: list[int]
    """The keep rule's validation tracks."""
    backoff: float | None
    """The explore job's back-off eps (``None``: none)."""
    frames_on_disk: bool
    """Each retraining reads its frames from one frame file."""
    env_config: Any
    """The environment the rounds roll out in."""
    demos_path: str
    """The demonstrations, as recorded with every round's net."""
    action_bounds: tuple[Any, Any]
    """The task's action bounds."""
    frame_stack: int
    """Frames the agent sees at once."""


def plan_selfimprove(
    start: BCNet,
    run_config: RunConfig,
    demos: Demonstrations,
    demos_path: str | Path,
    env_config: Any,
    config: SelfImproveConfig,
    action_bounds: tuple[Any, Any],
    frames_on_disk: bool | None,
) -> SelfImprovePlan:
    """The :class:`SelfImprovePlan` of a run (``frames_on_disk=None``: when the observations
    are ``uint8`` frames)."""
    from safe_bc.methods.experiment import select_for

    if not config.resolved:
        raise ValueError("run_selfimprove needs a resolved config: config.for_task(task)")
    assert config.rounds is not None and config.kept_in is not None
    pushes = config.pushes
    assert pushes is not None
    base = select_for(demos, run_config.selection)
    retrain = with_batches(run_config, config.batches)
    if config.alpha is not None:
        retrain = replace(retrain, selection=replace(retrain.selection, alpha=config.alpha))
    start_src = NetSource.from_model(start, run_config.bc)
    identity = {
        "format": FORMAT,
        "config": {**config.identity(), "pushes": list(pushes)},
        "run_config": run_config.to_dict(),
        "demos": repo_relative(demos_path),
        "env": str(env_config),
        "start_weights_sha256": weights_digest(start_src.state),
    }
    sel = run_config.selection
    backoff = None
    if config.backoff:
        backoff = sel.eps if config.backoff_eps is None else config.backoff_eps
    if frames_on_disk is None:
        obs = demos.observations
        frames_on_disk = obs.dtype == np.uint8 and len(obs.shape) == 4
    return SelfImprovePlan(
        config=config,
        pushes=tuple(pushes),
        base=base,
        limits=tuple(float(x) for x in base.thresholds),
        retrain=retrain,
        selection=sel,
        start=start_src,
        identity=identity,
        validation_seeds=validation_seeds(config.validation_episodes),
        backoff=backoff,
        frames_on_disk=bool(frames_on_disk),
        env_config=env_config,
        demos_path=str(demos_path),
        action_bounds=action_bounds,
        frame_stack=run_config.bc.preprocess.frame_stack,
    )


@dataclass
class _Progress:
    """Where a run's rounds stand: the current agent and the kept rows it was trained on."""

    agent: Any
    """The agent the next round starts from."""
    agent_name: str
    """``start`` or the last accepted round's folder."""
    reward_now: float
    """The current agent's validation reward (a round must beat it)."""
    kept_so_far: list[KeptPiece] = field(default_factory=list)
    """Accepted rows read so far (frame-less placeholders when the frames stay on disk)."""
    kept_sources: list[tuple[int, int, Path]] = field(default_factory=list)
    """The rounds of :attr:`kept_so_far`, in order: ``(round, rows, round file)``."""
    kept_files: list[tuple[int, Path]] = field(default_factory=list)
    """Accepted done rounds' kept rows, read when a round must run: ``(round, round file)``."""
    store: KeptFrameStore | None = None
    """The run's kept frames (``frames_on_disk``)."""
    rounds: list[dict[str, Any]] = field(default_factory=list)
    """Each round's ``done.json``."""
    resumed: int = 0
    """Rounds found done when the call began."""


def _validate(plan: SelfImprovePlan, rollouts: RolloutFn, agent: NetSource) -> dict[str, float]:
    """``agent`` on the validation tracks: episodes beyond ``d_s``, reward, env steps."""
    sel, config = plan.selection, plan.config
    job = ValidateJob(
        plan.env_config, agent, plan.limits, sel.eps, sel.combine, config.max_steps,
        config.lockstep_envs, config.lockstep_forward,
    )  # fmt: skip
    rows = rollouts(job, plan.validation_seeds)
    return {
        "validation_beyond": int(sum(m["any_violation"] > 0 for m in rows)),
        "validation_reward": float(np.mean([m["reward"] for m in rows])),
        "validation_env_steps": int(sum(m["steps"] for m in rows)),
    }


def validation_ingredients(plan: SelfImprovePlan, agent: NetSource) -> dict[str, Any]:
    """What makes ``agent``'s validation (:func:`_validate`), as a shared result's key: the
    agent (weights digest, net and BC configs), the env as the run identity writes it, the
    validation tracks, ``d_s``, the selection's eps and combine, the step cap and the
    lockstep settings."""
    sel, config = plan.selection, plan.config
    return {
        "kind": "selfimprove.validation",
        "format": SHARED_FORMAT,
        "agent": {
            "weights_sha256": weights_digest(agent.state),
            "spec": agent.spec,
            "bc": agent.config,
        },
        "env": str(plan.env_config),
        "tracks": [int(s) for s in plan.validation_seeds],
        "limits": [float(x) for x in plan.limits],
        "eps": float(sel.eps),
        "combine": str(sel.combine),
        "max_steps": config.max_steps,
        "lockstep_envs": int(config.lockstep_envs),
        "forward": str(config.lockstep_forward),
    }


def expert_run_ingredients(plan: SelfImprovePlan, job: ExpertRunsJob, seed: int) -> dict[str, Any]:
    """What makes the expert's own run on track ``seed`` (:class:`ExpertRunsJob`), as a shared
    result's key: the expert's config, the env as the run identity writes it, the track, the
    episode generator's seeds and the step cap."""
    from safe_bc.rollout.collect import config_dict

    return {
        "kind": "selfimprove.expert_run",
        "format": SHARED_FORMAT,
        "expert": config_dict(job.expert),
        "env": str(plan.env_config),
        "track": int(seed),
        "rng": [int(job.rng_seed), int(seed), int(job.rng_index)],
        "max_steps": job.max_steps,
    }


def _start_validation(
    plan: SelfImprovePlan, rollouts: RolloutFn, shared: SharedResults | None
) -> dict[str, Any]:
    """The start's validation record (``start_validation.json``), read from ``shared`` where
    a run of the same start and validation settings stored it (``shared_hits``: 1), else run
    (and stored there)."""
    t0 = time.perf_counter()
    val, hits = None, 0
    if shared is not None:
        key = validation_ingredients(plan, plan.start)
        val = shared.get(key)
        if val is not None:
            hits = 1
            _log.info("the start's validation read from %s", shared.path(key))
    if val is None:
        val = _validate(plan, rollouts, plan.start)
        if shared is not None:
            shared.put(key, val)
    record = {**val, "validation_episodes": len(plan.validation_seeds)}
    record["seconds"] = time.perf_counter() - t0
    if shared is not None:
        record["shared_hits"] = hits
    return record


def _expert_bars(
    plan: SelfImprovePlan,
    job: ExploreJob,
    seeds: Sequence[int],
    rollouts: RolloutFn,
    shared: SharedResults,
) -> tuple[dict[int, ExpertRun], int]:
    """The expert's own runs on ``seeds`` (the bars of ``keep_against="expert"``): those a run
    with the same expert, tracks and settings stored in ``shared`` read, the rest run (one
    :class:`ExpertRunsJob`) and stored; ``(bars by track, runs read)``."""
    runs_job = job.expert_runs()
    keys = {int(s): expert_run_ingredients(plan, runs_job, s) for s in seeds}
    bars: dict[int, ExpertRun] = {}
    for s, key in keys.items():
        found = shared.get(key)
        if found is not None:
            bars[s] = expert_run_from_json(found)
    hits = len(bars)
    missing = [s for s in keys if s not in bars]
    if missing:
        for s, run in zip(missing, rollouts(runs_job, missing), strict=True):
            shared.put(keys[s], expert_run_to_json(run))
            bars[s] = run
    if hits:
        _log.info("%d of the expert's %d runs read from %s", hits, len(keys), shared.folder)
    return bars, hits


def run_selfimprove(
    start: BCNet,
    run_config: RunConfig,
    demos: Demonstrations,
    demos_path: str | Path,
    env_config: Any,
    folder: str | Path,
    config: SelfImproveConfig,
    *,
    action_bounds: tuple[Any, Any],
    rollouts: RolloutFn = local_rollouts,
    train: TrainFn = train_local,
    on_round: Callable[[dict[str, Any]], None] | None = None,
    frames_on_disk: bool | None = None,
    shared: str | Path | None = None,
) -> SelfImproveResult:
    """Run (or resume) the rounds of ``config`` from the trained net ``start`` in ``folder``.

    ``run_config`` is the start's (selection and BC settings; ``config.batches`` overrides the
    batches of each retraining); ``config`` is resolved (:meth:`SelfImproveConfig.for_task`:
    its pushes, rounds and where kept rows go are set). A folder of another
    start, run config, demonstrations or config raises ``ValueError``.

    ``frames_on_disk`` (``None``: when the observations are ``uint8`` frames): the kept frames
    go raw into the run's append-only store (``kept_frames.bin``,
    :class:`~safe_bc.methods.selfimprove.store.KeptFrameStore`; the round files hold the rest)
    and each retraining reads the frames of the demonstrations and of every kept row from disk
    instead of holding them in memory: a CarRacing round keeps ~80k frames (~2 GB), so four
    accepted rounds held in memory and concatenated peaked near 19 GB. The same rows, batches
    and weights either way.

    ``shared`` (a comparison's ``<runs folder>/_shared``; ``None``: nothing shared): the
    start's validation and, with ``keep_against="expert"``, the expert's runs on the training
    tracks are read from there where another run stored them (content-keyed,
    :mod:`~safe_bc.methods.selfimprove.shared`), else run and stored: the same weights and
    round records (``shared_hits`` aside: what was read, in the start's validation record
    and each round's), the env steps the run needed counted as before.
    """
    plan = plan_selfimprove(
        start, run_config, demos, demos_path, env_config, config, action_bounds, frames_on_disk
    )
    folder = Path(folder)
    check_identity(folder / IDENTITY, plan.identity, "self-imitation run", "config")
    if not (folder / "start" / "config.json").is_file():  # the final agent when none is kept
        with checkpoint_unit(folder / "start") as unit:
            save_checkpoint(
                unit, start, run_config.bc,
                extra={"env_id": getattr(env_config, "env_id", None),
                       "demos": repo_relative(demos_path)},
            )  # fmt: skip
    cache = None if shared is None else SharedResults(shared)
    start_val = read_json(folder / START_VALIDATION)
    if start_val is None:
        start_val = _start_validation(plan, rollouts, cache)
        write_json_atomic(folder / START_VALIDATION, start_val)
    expert_side = _expert_side(config, demos_path, env_config)
    state = _Progress(plan.start, "start", float(start_val["validation_reward"]))
    if plan.frames_on_disk:
        state.store = KeptFrameStore(folder, tuple(demos.observations.shape[1:]))

    def write_curve_so_far() -> None:
        rows = SelfImproveResult(
            folder, state.rounds, state.resumed, state.agent_name, start_val
        ).history()
        write_curve(folder / CURVE, pd.DataFrame(rows), "iteration", "selfimprove", plan.identity)

    if not (had_curve := (folder / CURVE).is_file()):  # a rerun of done rounds keeps it
        write_curve_so_far()
    assert config.rounds is not None
    for r in range(config.rounds):
        here = folder / round_dir(r)
        done = read_json(here / DONE)
        if done is not None and (here / POLICY / "config.json").is_file():
            state.rounds.append(done)
            state.resumed += 1 if state.resumed == r else 0
            if done["accepted"]:
                state.kept_files.append((r, here / KEPT))
                state.agent, state.agent_name = policy_source(here / POLICY), round_dir(r)
                state.reward_now = float(done["validation_reward"])
            continue
        summary = _self_round(plan, here, r, state, demos, expert_side, rollouts, train, cache)
        write_json_atomic(here / DONE, summary)
        if state.store is not None:
            state.store.settle(r, bool(summary["accepted"]))
        state.rounds.append(summary)
        write_curve_so_far()
        if on_round is not None:
            on_round(summary)
    if state.resumed == len(state.rounds) and not had_curve:
        write_curve_so_far()  # a run whose rounds were all done before its curve existed
    return SelfImproveResult(folder, state.rounds, state.resumed, state.agent_name, start_val)


def _self_round(
    plan: SelfImprovePlan,
    here: Path,
    r: int,
    state: _Progress,
    demos: Demonstrations,
    expert_side: tuple[Any, Any, tuple[str, ...]],
    rollouts: RolloutFn,
    train: TrainFn,
    shared: SharedResults | None = None,
) -> dict[str, Any]:
    """Round ``r`` in ``here``: explore from the current agent (or read the rows kept before),
    retrain on the kept rows so far plus this round's, write the net, validate it and apply
    the keep rule (``state`` moves on when accepted); the round's ``done.json`` (with
    ``shared``: ``shared_hits``, the expert's runs read from it)."""
    config, frames_on_disk = plan.config, plan.frames_on_disk
    for done_r, f in state.kept_files:
        pieces = [p for t in load_round(f, not frames_on_disk) for p in t.pieces]
        state.kept_so_far += pieces
        state.kept_sources.append((done_r, sum(len(p.steps) for p in pieces), f))
    state.kept_files = []
    if state.store is not None:
        _sync_store(state.store, state.kept_sources, r, here / KEPT)
    t0 = time.perf_counter()
    hits = 0
    if (here / KEPT).is_file():
        tracks: list[TrackResult] = load_round(here / KEPT)
        if state.store is not None and holds_frames(here / KEPT):  # written before the store
            state.store.append(r, round_frames(tracks))
    else:
        job = ExploreJob(
            plan.env_config, state.agent, plan.pushes, plan.action_bounds, plan.limits,
            config.keep_unit, config.segment_steps, config.margin, plan.backoff,
            plan.frame_stack, config.max_steps, config.seed, config.keep_against,
            config.keep_best, *expert_side, config.lockstep_envs, config.lockstep_forward,
        )  # fmt: skip
        seeds = track_seeds(config.seed, r, config.tracks_per_round)
        if shared is not None and config.keep_against == "expert":
            bars, hits = _expert_bars(plan, job, seeds, rollouts, shared)
            job = replace(job, bars=bars)
        tracks = rollouts(job, seeds)
        if state.store is not None:  # frames first: a round file without them needs them there
            state.store.append(r, round_frames(tracks))
        save_round(here / KEPT, tracks, frames=state.store is None)
    if state.store is not None:  # the frames are in the store: read from disk when training
        tracks = [replace(t, pieces=tuple(frameless(p) for p in t.pieces)) for t in tracks]
    t_roll = time.perf_counter() - t0
    mine = [p for t in tracks for p in t.pieces]
    selection, source = _retrain(plan, here, r, state, demos, mine, train)
    val = _validate(plan, rollouts, source)
    accepted, bound = accept_round(
        val["validation_beyond"], config.validation_episodes, val["validation_reward"],
        state.reward_now, config.beyond_limit,
    )  # fmt: skip
    rollout, extras = round_summary(r, tracks, mine, selection, config)
    summary = {
        **rollout,
        **val,
        "previous_validation_reward": state.reward_now,
        "validation_beyond_upper": bound,
        "accepted": accepted,
        "rollout_seconds": t_roll,
        "seconds": time.perf_counter() - t0,
        **extras,
    }
    if shared is not None:
        summary["shared_hits"] = hits
    if accepted:
        state.agent, state.agent_name = source, round_dir(r)
        state.reward_now = val["validation_reward"]
        state.kept_so_far += mine  # frame-less when the frames are in the store
        state.kept_sources.append((r, sum(len(p.steps) for p in mine), here / KEPT))
    summary["agent"] = state.agent_name
    return summary


def _retrain(
    plan: SelfImprovePlan,
    here: Path,
    r: int,
    state: _Progress,
    demos: Demonstrations,
    mine: list[KeptPiece],
    train: TrainFn,
) -> tuple[Any, Any]:
    """BC retrained from scratch on the demonstrations, the kept rows so far and ``mine``
    (frames read from the demonstrations and the kept-frame store when they stay on disk), its
    net written: ``(selection, source)``."""
    config, retrain = plan.config, plan.retrain
    pieces = state.kept_so_far + mine
    frames = None
    if state.store is not None:
        frames = ConcatFrames([demos.observations, state.store.frames()])
    data, kept = aggregate_rows(demos, pieces, [p.trained for p in pieces], frames)
    assert config.kept_in is not None
    selection = kept_selection(
        data.costs, data.scored, kept, retrain.selection, plan.base.thresholds, config.kept_in
    )
    try:
        source = train(
            TrainJob(data, selection, retrain, plan.action_bounds, curve=here / ROUND_CURVE)
        )
    finally:
        if frames is not None:
            frames.close()
    save_round_net(
        here / POLICY,
        source,
        retrain.bc,
        "selfimprove",
        plan.identity,
        r,
        plan.env_config,
        plan.demos_path,
    )
    return selection, source


def _sync_store(
    store: KeptFrameStore, accepted: Sequence[tuple[int, int, Path]], r: int, kept: Path
) -> None:
    """Before round ``r`` runs: the store holds the frames of the ``accepted`` done rounds
    (``(round, rows, round file)``, in order) and, when round ``r``'s round file ``kept`` was
    written without its frames, that round's pending rows; anything else appended is cut (a
    round killed before it was settled). Accepted rounds whose round files hold their frames
    (a run folder from before the store) are appended from them. A round file of ``r``
    without frames whose rows the store lost is deleted: the round explores again (the same
    rows: rollouts are deterministic)."""
    pending = r if kept.is_file() and not holds_frames(kept) else None
    missing = store.reconcile([(a, n) for a, n, _ in accepted], pending)
    for a, _, f in accepted[len(accepted) - len(missing) :]:
        if not holds_frames(f):
            raise ValueError(
                f"{f}: its frames are in {store.path}, which lost them; delete the round "
                f"folders from round {a} on to rerun them"
            )
        store.append(a, round_frames(load_round(f)))
        store.settle(a, True)
    if pending is not None and not store.pending(r):
        kept.unlink()
