"""One study trial on Ray Tune: select, train, checkpoint, then evaluate in rounds.

A trial trains once (the first report carries the weights as a checkpoint, so a retry or a
resumed study never retrains: :func:`resume_point`), is screened on the first
``screen_episodes`` held-out tracks (successive halving may stop it there) and, if it
survives, evaluated on the rest of its ``eval_episodes`` tracks. Every report carries every
key of :func:`~safe_bc.study.spec.trial_metrics`.

Between the training and the evaluation, every stage the study sets
(:meth:`StudySpec.stages`, e.g. ``StudySpec.improve``: constrained RL beyond the
expert) turns each seed's agent into the one the rounds evaluate, in the trial's folder (resumable).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import random
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch
from ray import tune

from safe_bc.bc import CheckpointError, load_checkpoint, read_checkpoint_meta
from safe_bc.bc.net import BCNet
from safe_bc.bc.train import TrainResult, training_threads
from safe_bc.data.demos import Demonstrations
from safe_bc.data.store import (
    DatasetError,
    is_local_filesystem,
    load_demonstrations,
    read_table,
    subfolders,
    write_table_atomic,
)
from safe_bc.distributed.evaluate import evaluate_policies
from safe_bc.distributed.rollouts import ChunkedRayRollouts
from safe_bc.methods.experiment import RunConfig, save_curve, train_run
from safe_bc.methods.stages import run_stage
from safe_bc.metrics import cell_table, lower_bound_crossed, mean_metrics
from safe_bc.rollout.evaluate import EvalConfig, NetSource
from safe_bc.selection import SelectionError
from safe_bc.study.console import quiet_logs
from safe_bc.study.search import ROUND, SCORE, SCREENED, screen_score
from safe_bc.study.spec import (
    ConstraintBars,
    StudySpec,
    constraints,
    episode_share_bound,
    trial_metrics,
)
from safe_bc.tasks import Bounds, dataset_action_bounds


@dataclass(frozen=True)
class TrialJob:
    """What every trial of a study shares (pickled into the trainable; small)."""

    spec: StudySpec
    """The study."""
    demos: str
    """Absolute path of the demonstration set (trials run in their own folders)."""
    limits: ConstraintBars
    """The constraints' thresholds and tolerance (from the expert's demonstrations)."""
    cost_limits: tuple[float, ...]
    """The demonstrations' ``d_s`` (max cost per dimension): violations and critical share."""
    validation_demos: str | None = None
    """Absolute path of ``spec.validation_demos`` (the curves' held-out set), if any."""

    @property
    def threshold(self) -> float:
        """The safety-mean threshold."""
        return self.limits.threshold


_DEMOS: dict[str, Demonstrations] = {}
"""Per-process cache: ``reuse_actors=True`` keeps trial processes, so demos load once."""


def bounds_for(demos: str | Path) -> Bounds:
    """The action bounds of the demonstration set at ``demos`` (its ``dataset.json``, else
    its task's entry in :mod:`safe_bc.tasks`)."""
    return dataset_action_bounds(demos)


def cached_demos(path: str) -> Demonstrations:
    """The demonstration set at ``path``, loaded once per process."""
    if path not in _DEMOS:
        _DEMOS.clear()
        _DEMOS[path] = load_demonstrations(Path(path))
    return _DEMOS[path]


_VALIDATION: dict[str, Demonstrations] = {}
"""Per-process cache of the study's validation set (beside :data:`_DEMOS`)."""


def validation_demos(job: TrialJob) -> Demonstrations | None:
    """The study's validation set (``StudySpec.validation_demos``), loaded once per process."""
    path = job.validation_demos
    if path is None:
        return None
    if path not in _VALIDATION:
        _VALIDATION.clear()
        _VALIDATION[path] = load_demonstrations(Path(path))
    return _VALIDATION[path]


CURVE_FOLDER = "bc"
"""Folder (in :func:`trial_folder`) of the first training seed's learning curve
(``curve.parquet`` and its TensorBoard event files); ``bc_seed_<s>`` for the other seeds."""


def save_trial_curve(result: TrainResult, seed: int, first: bool, meta: dict[str, Any]) -> None:
    """Write one training seed's learning curve into the trial's folder."""
    folder = trial_folder() / (CURVE_FOLDER if first else f"{CURVE_FOLDER}_seed_{seed}")
    save_curve(folder, result, {**meta, "train_seed": seed})


def trial_threads(spec: StudySpec) -> int:
    """Torch threads every trial of ``spec`` trains with: ``base.bc.train.num_threads``, else 1.

    Never the CPU reservation (``cpus_per_trial``; Ray also sets ``OMP_NUM_THREADS`` from it)
    nor the reused process's setting: 1 and 2 threads give different weights, so the count is
    part of the trial's run config (recorded in its checkpoint) and a rerun with other
    resources, or ``train_run`` of that config in any process, gives the same weights.
    """
    return training_threads(spec.base.bc.train)


def reset_trial_state(seed: int) -> None:
    """Reset the global random state a reused trial process carries over."""
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def eval_rounds(spec: StudySpec) -> list[tuple[int, int]]:
    """``(first_episode, episodes)`` of each evaluation round: the screening, then the rest.

    >>> from safe_bc.study.spec import Float
    >>> eval_rounds(StudySpec("s", {"selection.alpha": Float(0, 1)}))
    [(0, 3), (3, 7)]
    """
    if spec.screens:
        first = spec.screen_episodes
        return [(0, first), (first, spec.eval_episodes - first)]
    return [(0, spec.eval_episodes)]


def blank_metrics(job: TrialJob) -> dict[str, Any]:
    """A report with every key of :func:`~safe_bc.study.spec.trial_metrics` (NaN where not
    known yet)."""
    spec = job.spec
    seeds = EvalConfig(episodes=spec.eval_episodes, seed=spec.eval_seed).seeds()
    out: dict[str, Any] = {k: math.nan for k in trial_metrics()}
    out.update(
        threshold=job.threshold,
        feasible=False,
        train_seed=spec.base.bc.train.seed,
        eval_seed=spec.eval_seed,
        eval_seeds=",".join(str(s) for s in seeds),
        episodes=0,
        resumed=False,
        phase="",
        error="",
    )
    out[ROUND] = 0  # the halving reads these on every report: round 0 is before any evaluation
    out[SCORE] = math.nan
    out[SCREENED] = math.nan  # the screening score, kept in the later reports
    return out


def evaluate_net(
    model: BCNet, run_cfg: RunConfig, job: TrialJob, first: int, n: int
) -> pd.DataFrame:
    """Held-out episodes ``first .. first + n - 1`` of the trial's seed block (one row each)."""
    return evaluate_source(NetSource.from_model(model, run_cfg.bc), run_cfg, job, first, n)


def evaluate_source(
    source: Any, run_cfg: RunConfig, job: TrialJob, first: int, n: int
) -> pd.DataFrame:
    """:func:`evaluate_net` for any policy source (e.g. an improved agent)."""
    spec = job.spec
    config = EvalConfig(
        episodes=n,
        first_episode=first,
        workers=spec.rollout_workers,
        seed=spec.eval_seed,
        env=spec.env,
        max_steps=spec.max_steps,
        eps=spec.critical_eps,
        combine=run_cfg.selection.combine,
    )
    episodes, _ = evaluate_policies(  # no summary: the trial's metrics are made from its rows
        {"trial": source},
        config,
        thresholds=np.asarray(job.cost_limits),
        progress=False,
        actor_cpus=spec.cpus_per_worker if spec.rollout_workers else None,
        envs_per_worker=spec.trial_envs,
    )
    return episodes


def trial_values(
    episodes: pd.DataFrame, limits: ConstraintBars, spec: StudySpec | None = None
) -> dict[str, float]:
    """A trial's metrics from its evaluated episodes (every training seed's, ``train_seed``
    column, on the same tracks): the means of ``metrics.METRICS`` over all episodes (the same
    definitions as every other table), the reward's lower confidence bound over the (seed,
    track) cells (``reward_lcb``, at ``spec.reward_bound``, else 95%), the upper bound on
    the share of episodes beyond ``d_s`` (``violation_share_ucb``, at ``spec.violation_bound``,
    else 95%) and the constraints."""
    means = mean_metrics(episodes)
    values = {k: v for k, v in means.items() if k not in ("reward", "steps")}
    values.update(
        reward_mean=means["reward"],
        reward_std=float(episodes["reward"].std(ddof=0)),
        steps_mean=means["steps"],
        episodes=len(episodes),
    )
    reward_conf = 0.95 if spec is None or spec.reward_bound is None else spec.reward_bound
    share_conf = 0.95 if spec is None or spec.violation_bound is None else spec.violation_bound
    tracks = episodes.assign(train_seed=episodes.get("train_seed", 0))
    cells = cell_table(tracks, "reward").to_numpy(float)
    values["reward_lcb"] = lower_bound_crossed(cells, reward_conf)
    values["violation_share_ucb"] = episode_share_bound(values, share_conf)
    values["train_seeds"] = int(tracks["train_seed"].nunique())
    values["deferred_share"] = (
        float(episodes["deferred_share"].mean()) if "deferred_share" in episodes else 0.0
    )
    values.update(constraints(values, limits))
    return values


def _load(checkpoint: tune.Checkpoint) -> tuple[BCNet, dict[str, Any]]:
    with checkpoint.as_directory() as d:
        model, _ = load_checkpoint(d)
        return model, read_checkpoint_meta(d)["extra"]


def _load_seeds(checkpoint: tune.Checkpoint) -> tuple[list[BCNet], dict[str, Any]]:
    """Every seed's net of a trial checkpoint: the first seed's at its top, the others (a
    trial with ``train_seeds > 1``) in ``seed_<s>/`` inside it."""
    with checkpoint.as_directory() as d:
        model, _ = load_checkpoint(d)
        extra = read_checkpoint_meta(d)["extra"]
        others = [load_checkpoint(Path(d) / f"seed_{s}")[0] for s in extra.get("seeds", [])[1:]]
        return [model, *others], extra


def stored_checkpoint(
    fs: Any, folder: str, *, all_seeds: bool = False
) -> tuple[Any, dict[str, Any]] | None:
    """The newest complete checkpoint among the ``checkpoint_*`` folders of a trial's folder
    ``folder`` on the ``pyarrow`` filesystem ``fs``: its net and ``extra`` (``None``: none);
    with ``all_seeds`` the list of every training seed's net instead of the first's."""
    dirs = [path for path, _ in subfolders(fs, folder, prefix="checkpoint_")]
    load = _load_seeds if all_seeds else _load
    for d in sorted(dirs, reverse=True):
        try:
            return load(tune.Checkpoint(d, filesystem=fs))
        except (CheckpointError, OSError):  # cut short by a kill: try an older one
            continue
    return None


def checkpoint_problem(path: str | Path) -> str:
    """Why the trial checkpoint folder ``path`` does not load whole, every training seed's net
    checked against its SHA-256 (``""``: it does)."""
    try:
        _load_seeds(tune.Checkpoint(str(path)))
    except (CheckpointError, OSError) as e:
        return " ".join(str(e).split())
    return ""


def resume_point() -> tuple[list[BCNet], dict[str, Any], bool] | None:
    """Every training seed's trained net, the checkpoint's ``extra`` and whether Tune had
    recorded the checkpoint, when this trial has trained before.

    Tune hands over the checkpoint it recorded (a retry, a resumed study); a damaged one is
    passed over for the newest whole one in the trial's folder, else the trial trains again
    from its start (instead of failing every retry on it). A checkpoint the
    trial reported just before the driver stopped (Ctrl-C, or killed) is on the storage but not
    in Tune's saved experiment state, and Tune then restarts the trial without one (Ray 2.60):
    the newest complete checkpoint in the trial's folder is used instead of retraining (and
    reported again: the driver may never have seen its ``trained`` report).
    """
    checkpoint = tune.get_checkpoint()
    if checkpoint is not None:
        try:
            return (*_load_seeds(checkpoint), True)
        except (CheckpointError, OSError):  # damaged (the driver names it): its last good state
            pass
    storage = tune.get_context().get_storage()
    stored = stored_checkpoint(storage.storage_filesystem, storage.trial_fs_path, all_seeds=True)
    return None if stored is None else (*stored, False)


def trial_folder() -> Path:
    """A folder of this trial that outlives retries and a resumed study: inside the trial's
    folder of the storage when that is local, else the trial's local folder."""
    storage = tune.get_context().get_storage()
    if is_local_filesystem(storage.storage_filesystem):
        return Path(storage.trial_fs_path)
    return Path(tune.get_context().get_trial_dir())


ROUNDS = "rounds"
"""Folder (in :func:`trial_folder`) of a trial's evaluated rounds: each round's episodes, kept
so that a trial restarted after its driver was killed (its report of the round made, Tune's
saved state not yet saying so) reports them again instead of evaluating them again."""


def round_file(run_cfg: RunConfig, spec: StudySpec, seeds: list[int], first: int, n: int) -> str:
    """``rounds/<first>_<n>_<digest>.parquet``: one evaluation round of a trial, keyed by
    everything its episodes depend on (the configuration, seeds, tracks, env, stages)."""
    key = {
        "run": run_cfg.to_dict(),
        "seeds": seeds,
        "first": first,
        "n": n,
        "eval_seed": spec.eval_seed,
        "env": str(spec.env),
        "max_steps": spec.max_steps,
        "eps": spec.critical_eps,
        "stages": [stage.name for stage in spec.stages()],
    }
    if spec.handover is not None:
        key["handover"] = {**spec.handover.to_dict(), "evaluation": "lockstep"}
    text = json.dumps(key, sort_keys=True, default=str)
    return f"{ROUNDS}/{first}_{n}_{hashlib.sha256(text.encode()).hexdigest()[:16]}.parquet"


def stored_round(path: Path) -> tuple[pd.DataFrame, float] | None:
    """A stored round's episodes and evaluation seconds (``None``: none, or unreadable)."""
    if not path.exists():
        return None
    try:
        episodes, meta = read_table(path)
    except DatasetError:
        return None
    return episodes, float(meta.get("eval_seconds", 0.0))


def with_handover(source: Any, job: TrialJob) -> Any:
    """``source`` (an agent) with the study's handover to the demonstrations' expert at their
    ``d_s``: the recommender the study evaluates."""
    from safe_bc.rollout.collect import stored_expert_config
    from safe_bc.rollout.handover import handover_source
    from safe_bc.tasks import task_defaults, task_of

    dims = task_defaults(task_of(job.spec.env.env_id)).safety_dims
    expert = stored_expert_config(Path(job.demos))
    return handover_source(source, job.spec.handover, expert, job.cost_limits, dims)


def with_seed(cfg: RunConfig, seed: int) -> RunConfig:
    """``cfg`` with another training seed."""
    train = dataclasses.replace(cfg.bc.train, seed=seed)
    return dataclasses.replace(cfg, bc=dataclasses.replace(cfg.bc, train=train))


def _report_invalid(metrics: dict[str, Any], error: str, start: float) -> None:
    """Report a trial whose configuration cannot be trained (no retry)."""
    metrics.update(phase="invalid", error=error, duration_s=time.perf_counter() - start)
    tune.report(metrics)


@dataclass(frozen=True)
class TrialPlan:
    """What one trial runs, decided from its sampled configuration and the study (pure)."""

    seeds: list[int]
    """The training seeds (the first one's agent is the trial's checkpoint)."""
    params: dict[str, Any]
    """The sampled parameters, in space order."""
    threads: int
    """Torch threads of the trial's process."""
    run_cfg: RunConfig
    """The trial's run configuration (the study's base with ``params`` applied)."""


def trial_plan(config: dict[str, Any], spec: StudySpec) -> TrialPlan:
    """The :class:`TrialPlan` of the trial sampled as ``config``."""
    threads = trial_threads(spec)
    params = {k: config[k] for k in spec.params}
    return TrialPlan(spec.trial_seeds(), params, threads, spec.run_config(params, threads))


def run_trial(config: dict[str, Any], job: TrialJob) -> None:
    """One trial: train every training seed (or resume from its checkpoint), report, run the
    study's stages, evaluate in rounds (every seed on the same tracks), report."""
    start = time.perf_counter()
    plan = trial_plan(config, job.spec)
    reset_trial_state(plan.seeds[0])
    quiet_logs()
    torch.set_num_threads(plan.threads)
    metrics = blank_metrics(job)
    trained = _resume_or_train(plan, job, metrics, start)
    if trained is None:  # a configuration the data cannot support: reported, no retry
        return
    models, earlier, store_s = trained
    sources = _run_stages(plan, job, models, metrics)
    _evaluate_rounds(plan, job, sources, metrics, start, earlier, store_s)


def _resume_or_train(
    plan: TrialPlan, job: TrialJob, metrics: dict[str, Any], start: float
) -> tuple[list[BCNet], float, float] | None:
    """The trial's trained nets, from its checkpoint (a retry or a resumed study) or trained
    and reported with a checkpoint: ``(models, seconds of an earlier run, storage seconds)``;
    ``None`` after reporting a configuration that cannot be trained."""
    resumed = resume_point()
    if resumed is None:
        return _train(plan, job, metrics, start)
    models, extra, recorded = resumed
    metrics.update(extra["train"], resumed=True)
    earlier = float(extra["trained_s"])
    if not recorded:  # its trained report may be lost with the driver: the row again
        tune.report({**metrics, "phase": "trained", "duration_s": earlier})
    return models, earlier, 0.0  # the earlier run's checkpoint time is not known


def _train(
    plan: TrialPlan, job: TrialJob, metrics: dict[str, Any], start: float
) -> tuple[list[BCNet], float, float] | None:
    """Train every seed, then report the trained row with the checkpoint (every seed's net)."""
    seeds, run_cfg = plan.seeds, plan.run_cfg
    results = []
    for s in seeds:
        if s != seeds[0]:
            reset_trial_state(s)
        try:
            result, selection = train_run(
                cached_demos(job.demos), with_seed(run_cfg, s),
                action_bounds=bounds_for(job.demos), validation=validation_demos(job),
            )  # fmt: skip
        except SelectionError as e:  # a configuration the data cannot support: no retry
            _report_invalid(metrics, str(e), start)
            return None
        if not math.isfinite(result.final_loss):  # diverged: nothing to evaluate, no retry
            _report_invalid(metrics, f"training diverged (loss {result.final_loss})", start)
            return None
        if s == seeds[0]:
            first_selection = selection
        save_trial_curve(result, s, s == seeds[0], {"params": plan.params})
        results.append(result)
    train_info = {
        "train_loss": results[0].final_loss,
        "train_seconds": float(sum(r.seconds for r in results)),
        "n_critical": first_selection.n_critical,
        "critical_fraction": first_selection.n_critical / first_selection.n_valid,
    }
    trained_s = time.perf_counter() - start
    metrics.update(train_info, phase="trained", duration_s=trained_s)
    extra = {"train": train_info, "trained_s": trained_s, "run_config": run_cfg.to_dict()}
    if len(seeds) > 1:
        extra["seeds"] = seeds
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        results[0].save(d, extra=extra)
        for s, result in zip(seeds[1:], results[1:], strict=True):
            result.save(Path(d) / f"seed_{s}", extra={"seed": s})
        metrics.update(store_seconds=time.perf_counter() - t0)
        tune.report(metrics, checkpoint=tune.Checkpoint.from_directory(d))
    # the checkpoint's copy to the storage happens in the report: counted from the next one
    return [r.model for r in results], 0.0, time.perf_counter() - t0


def _run_stages(
    plan: TrialPlan, job: TrialJob, models: list[BCNet], metrics: dict[str, Any]
) -> list[Any]:
    """The study's stages on every seed's agent (their time counts in ``duration_s``, not in
    ``eval_seconds``); the sources to evaluate, with the task's handover where the study has
    one."""
    spec, seeds, run_cfg = job.spec, plan.seeds, plan.run_cfg
    sources: list[Any] = [NetSource.from_model(m, run_cfg.bc) for m in models]
    agents: list[Any] = list(models)
    for stage in spec.stages():
        name, per_seed = stage.name, []
        for j, s in enumerate(seeds):
            folder = trial_folder() / (name if j == 0 else f"{name}_seed_{s}")
            agents[j], values = run_stage(
                stage, spec.stage_config(name, plan.params, seed=s), agents[j],
                with_seed(run_cfg, s), job.demos, spec.env.env_id, folder,
                parallel=ChunkedRayRollouts,
            )  # fmt: skip
            sources[j] = agents[j]
            per_seed.append(values)
        metrics.update(stage.reduce(per_seed))
    if spec.handover is not None:  # the trial's recommender: the agent with its handover
        sources = [with_handover(source, job) for source in sources]
    return sources


def _evaluate_rounds(
    plan: TrialPlan,
    job: TrialJob,
    sources: list[Any],
    metrics: dict[str, Any],
    start: float,
    earlier: float,
    store_s: float,
) -> None:
    """Evaluate every seed's source round by round on the same tracks (a round stored before
    is read back), reporting the trial's values after each round."""
    spec, seeds, run_cfg = job.spec, plan.seeds, plan.run_cfg
    rounds = eval_rounds(spec)
    parts: list[pd.DataFrame] = []
    eval_s = 0.0
    folder = trial_folder()
    for i, (first, n) in enumerate(rounds, start=1):
        path = folder / round_file(run_cfg, spec, seeds, first, n)
        stored = stored_round(path)
        if stored is None:  # not evaluated before this trial was stopped or its driver killed
            t0 = time.perf_counter()
            episodes = pd.concat(
                [
                    evaluate_source(source, run_cfg, job, first, n).assign(train_seed=s)
                    for s, source in zip(seeds, sources, strict=True)
                ],
                ignore_index=True,
            )
            seconds = time.perf_counter() - t0
            t0 = time.perf_counter()
            write_table_atomic(path, episodes, {"eval_seconds": seconds})
            store_s += time.perf_counter() - t0
        else:
            episodes, seconds = stored
        parts.append(episodes)
        eval_s += seconds
        values = trial_values(pd.concat(parts, ignore_index=True), job.limits, spec)
        metrics.update(
            values,
            phase="evaluated" if i == len(rounds) else "screened",
            eval_seconds=eval_s,
            round_eval_seconds=seconds,
            store_seconds=store_s,
            duration_s=earlier + time.perf_counter() - start,
            feasible=bool(values["constraint"] <= 0),
        )
        metrics[ROUND] = i
        metrics[SCORE] = screen_score(values[spec.objective], values["constraint"])
        if i == 1:
            metrics[SCREENED] = metrics[SCORE]
        tune.report(metrics)
