"""Running a ``StudySpec`` on Ray Tune + Optuna: constrained search, resumable, re-evaluated.

* :class:`ConstrainedOptunaSearch` hands each finished trial's safety constraint to Optuna
  (``Trial.set_constraint``) before the usual ``tell``; Ray's ``OptunaSearch`` alone drops it.
* :func:`run_trial` is one trial: select, train, checkpoint, evaluate on held-out seeds.
* :func:`run_study` builds or restores the Tuner, writes ``trials.parquet``,
  ``history.parquet`` and ``pareto.png``, picks the winner from the table and re-evaluates it
  beside the expert and the alpha = 0 baseline (``final.parquet``, ``best.json``).
"""

from __future__ import annotations

import json
import math
import os
import random
import signal
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch
from optuna.samplers import TPESampler
from ray import tune
from ray.tune.logger import CSVLoggerCallback, JsonLoggerCallback
from ray.tune.search.optuna import OptunaSearch
from ray.tune.utils import flatten_dict

from safe_bc.bc import load_checkpoint, read_checkpoint_meta
from safe_bc.bc.policy import BCNet
from safe_bc.collection import stored_expert_config
from safe_bc.data.store import (
    load_demonstrations,
    read_meta,
    write_table_atomic,
    write_text_atomic,
)
from safe_bc.demos import Demonstrations
from safe_bc.distributed.evaluate import evaluate_policies
from safe_bc.distributed.runtime import ensure_ray
from safe_bc.evaluation import EvalConfig, ExpertSource, NetSource
from safe_bc.experiment import RunConfig, train_run
from safe_bc.metrics import combined, summarize
from safe_bc.provenance import provenance
from safe_bc.seeds import heldout_seeds
from safe_bc.selection import SelectionError, thresholds
from safe_bc.study import (
    CONSTRAINT,
    OBJECTIVE,
    TRIAL_METRICS,
    Choice,
    Float,
    Int,
    Param,
    StudySpec,
    Winner,
    choose_winner,
    constraint_value,
    is_feasible,
    is_missing,
    plot_pareto,
    summary_lines,
    trial_table,
)
from safe_bc.tasks import action_bounds, task_defaults, task_of

CONSTRAINT_NAME = "safety"
"""Key of the constraint inside Optuna (``trial.constraints["safety"]``)."""

FINAL_METRICS = (
    "reward",
    "safety_mean",
    "safety_std",
    "safety_min",
    "offroad_steps",
    "critical_share",
    "tiles_visited",
)
"""Summarised with bootstrap CIs in ``final.parquet``."""


# --- the searcher -----------------------------------------------------------------------------


class SpaceSampler:
    """Optuna define-by-run function for a ``StudySpec.space`` (plain data: pickles by value,
    so the checkpointed searcher restores without the study file)."""

    def __init__(self, space: Mapping[str, Param]) -> None:
        self.space = dict(space)

    def __call__(self, trial: Any) -> None:
        for name, p in self.space.items():
            if isinstance(p, Float):
                trial.suggest_float(name, p.low, p.high, log=p.log)
            elif isinstance(p, Int):
                trial.suggest_int(name, p.low, p.high, step=p.step, log=p.log)
            elif isinstance(p, Choice):
                trial.suggest_categorical(name, list(p.labels()))
            else:  # pragma: no cover - StudySpec validates the space
                raise TypeError(f"unknown parameter type {type(p).__name__}")


class ConstrainedOptunaSearch(OptunaSearch):
    """``OptunaSearch`` that passes ``result[constraint_key]`` to Optuna as a constraint.

    Ray's ``OptunaSearch`` ignores ``TPESampler(constraints_func=...)`` silently; Optuna 5
    reads constraints that ``Trial.set_constraint(name, value)`` stored on the trial
    (``value <= 0`` feasible), so they are set in ``on_trial_complete`` before ``tell``.
    Results whose objective is not a finite number (the post-training report) are not
    forwarded as intermediate values.
    """

    def __init__(
        self,
        *args: Any,
        constraint_key: str = CONSTRAINT,
        constraint_name: str = CONSTRAINT_NAME,
        **kwargs: Any,
    ) -> None:
        self._constraint_key = constraint_key
        self._constraint_name = constraint_name
        super().__init__(*args, **kwargs)

    def on_trial_result(self, trial_id: str, result: dict) -> None:
        value = result.get(self.metric) if isinstance(self.metric, str) else None
        if isinstance(value, int | float) and math.isfinite(value):
            super().on_trial_result(trial_id, result)

    def on_trial_complete(
        self, trial_id: str, result: dict | None = None, error: bool = False
    ) -> None:
        ot_trial = self._ot_trials.get(trial_id)
        if ot_trial is not None and trial_id not in self._completed_trials and result:
            value = result.get(self._constraint_key)
            if isinstance(value, int | float) and math.isfinite(value):
                if self._constraint_name not in ot_trial.constraints:
                    ot_trial.set_constraint(self._constraint_name, float(value))
            elif not error:
                # No constraint (e.g. an invalid configuration): not a usable point.
                error = True
                result = {k: v for k, v in result.items() if k != self.metric}
        super().on_trial_complete(trial_id, result, error)

    @property
    def study(self) -> Any:
        """The Optuna study (its trials carry ``.constraints``)."""
        return self._ot_study

    def constraints_by_trial(self) -> dict[str, dict[str, float]]:
        """Tune trial id -> the constraint values Optuna holds for that trial."""
        return {tid: dict(t.constraints) for tid, t in self._ot_trials.items()}


def make_searcher(spec: StudySpec) -> ConstrainedOptunaSearch:
    """The study's constrained TPE searcher (maximises ``reward_mean``)."""
    sampler = TPESampler(
        seed=spec.sampler_seed,
        n_startup_trials=spec.startup_trials,
        multivariate=True,
        constant_liar=spec.max_concurrent > 1,
    )
    return ConstrainedOptunaSearch(
        space=SpaceSampler(spec.space),
        metric=OBJECTIVE,
        mode="max",
        sampler=sampler,
        study_name=spec.name,
    )


def load_searcher(experiment_path: str | Path) -> ConstrainedOptunaSearch:
    """The searcher as last checkpointed in a (local) experiment folder."""
    searcher = ConstrainedOptunaSearch()
    searcher.restore_from_dir(str(experiment_path))
    return searcher


# --- one trial ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class TrialJob:
    """What every trial of a study shares (pickled into the trainable; small)."""

    spec: StudySpec
    """The study."""
    demos: str
    """Absolute path of the demonstration set (trials run in their own folders)."""
    threshold: float
    """Safety threshold of the constraint."""
    cost_thresholds: tuple[float, ...]
    """The demonstrations' ``d_s`` (max cost per dimension) behind ``critical_share``."""


_DEMOS: dict[str, Demonstrations] = {}
"""Per-process cache: ``reuse_actors=True`` keeps trial processes, so demos load once."""


def _bounds(spec: StudySpec) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
    """Action bounds for vector tasks (CarRacing's are the frames' default)."""
    return None if spec.env.is_carracing else action_bounds(spec.env)


def cached_demos(path: str) -> Demonstrations:
    """The demonstration set at ``path``, loaded once per process."""
    if path not in _DEMOS:
        _DEMOS.clear()
        _DEMOS[path] = load_demonstrations(Path(path))
    return _DEMOS[path]


def trial_threads(cpus: float) -> int:
    """Torch threads for a trial reserving ``cpus`` CPUs."""
    return max(1, int(cpus))


def reset_trial_state(seed: int) -> None:
    """Reset the global random state a reused trial process carries over."""
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def _blank_metrics(job: TrialJob) -> dict[str, Any]:
    spec = job.spec
    seeds = heldout_seeds(spec.eval_seed, spec.eval_episodes)
    out: dict[str, Any] = {k: math.nan for k in TRIAL_METRICS}
    out.update(
        threshold=job.threshold,
        feasible=False,
        train_seed=spec.base.bc.train.seed,
        eval_seed=spec.eval_seed,
        eval_seeds=",".join(str(s) for s in seeds),
        resumed=False,
        phase="",
        error="",
    )
    return out


def evaluate_trial(
    model: BCNet, run_cfg: RunConfig, job: TrialJob
) -> tuple[dict[str, float], float]:
    """Held-out evaluation of a trained net: ``(metrics, seconds)``.

    Safety statistics pool the scored (non-warm-up) steps of all episodes, like the
    threshold pools the demonstrations' scored steps.
    """
    spec = job.spec
    start = time.perf_counter()
    config = EvalConfig(
        episodes=spec.eval_episodes,
        workers=spec.rollout_workers,
        seed=spec.eval_seed,
        env=spec.env,
        max_steps=spec.max_steps,
        eps=spec.critical_eps,
    )
    episodes, steps = evaluate_policies(
        {"trial": NetSource.from_model(model, run_cfg.bc)},
        config,
        thresholds=np.asarray(job.cost_thresholds),
        progress=False,
        actor_cpus=spec.cpus_per_worker if spec.rollout_workers else None,
    )
    return episode_summary(episodes, steps), time.perf_counter() - start


def episode_summary(episodes: pd.DataFrame, steps: pd.DataFrame) -> dict[str, float]:
    """Trial metrics from ``evaluate_policies`` output (one policy)."""
    scored = steps[~steps["warmup"].astype(bool)]
    safety = scored["safety"].to_numpy(float)
    critical = scored["critical"].to_numpy(bool) if "critical" in scored else np.array([])
    return {
        "reward_mean": float(episodes["reward"].mean()),
        "reward_std": float(episodes["reward"].std(ddof=0)),
        "safety_mean": float(safety.mean()),
        "safety_std": float(safety.std()),
        "safety_min": float(safety.min()),
        "offroad_steps": float(episodes["offroad_steps"].mean()),
        "critical_share": float(critical.mean()) if len(critical) else math.nan,
        "steps_mean": float(episodes["steps"].mean()),
    }


def run_trial(config: dict[str, Any], job: TrialJob) -> None:
    """One trial: train (or resume from its checkpoint), report, evaluate, report.

    The first report carries the trained weights as a checkpoint, so a retry after a
    failure (or a resumed study) evaluates without retraining.
    """
    start = time.perf_counter()
    spec = job.spec
    seed = spec.base.bc.train.seed
    reset_trial_state(seed)
    threads = trial_threads(spec.cpus_per_trial)
    torch.set_num_threads(threads)
    run_cfg = spec.run_config({k: config[k] for k in spec.params}, num_threads=threads)
    metrics = _blank_metrics(job)

    checkpoint = tune.get_checkpoint()
    if checkpoint is not None:  # a retry or a resumed study: the weights are already trained
        with checkpoint.as_directory() as d:
            model, _ = load_checkpoint(d)
            extra = read_checkpoint_meta(d)["extra"]
        metrics.update(extra["train"], resumed=True)
        earlier = float(extra["trained_s"])
    else:
        try:
            result, selection = train_run(
                cached_demos(job.demos), run_cfg, action_bounds=_bounds(spec)
            )
        except SelectionError as e:  # a configuration the data cannot support: no retry
            metrics.update(phase="invalid", error=str(e), duration_s=time.perf_counter() - start)
            tune.report(metrics)
            return
        if not math.isfinite(result.final_loss):  # diverged: nothing to evaluate, no retry
            metrics.update(phase="invalid", error=f"training diverged (loss {result.final_loss})")
            metrics.update(duration_s=time.perf_counter() - start)
            tune.report(metrics)
            return
        model, earlier = result.model, 0.0
        train_info = {
            "train_loss": result.final_loss,
            "train_seconds": result.seconds,
            "n_critical": selection.n_critical,
            "critical_fraction": selection.n_critical / selection.n_valid,
        }
        trained_s = time.perf_counter() - start
        metrics.update(train_info, phase="trained", duration_s=trained_s)
        extra = {"train": train_info, "trained_s": trained_s, "run_config": run_cfg.to_dict()}
        with tempfile.TemporaryDirectory() as d:
            result.save(d, extra=extra)
            tune.report(metrics, checkpoint=tune.Checkpoint.from_directory(d))

    values, eval_s = evaluate_trial(model, run_cfg, job)
    c = constraint_value(job.threshold, values["safety_mean"])
    metrics.update(
        values,
        phase="evaluated",
        eval_seconds=eval_s,
        duration_s=earlier + time.perf_counter() - start,
        constraint=c,
        feasible=is_feasible(c),
    )
    tune.report(metrics)


# --- the study ----------------------------------------------------------------------------------

HISTORY = "history.jsonl"
"""Every reported result as it arrived (``history.parquet`` is made from it)."""


@dataclass(frozen=True)
class StudyOutcome:
    """What :func:`run_study` did."""

    complete: bool
    """All trials finished (an interrupted study is resumed by running it again)."""
    trials: pd.DataFrame
    """The trial table (also ``trials.parquet``)."""
    winner: Winner | None
    """The chosen trial (``None`` while incomplete or when nothing finished)."""
    final: pd.DataFrame | None
    """The re-evaluation summary (``final.parquet``), or ``None``."""
    threshold: float
    """The safety threshold used."""
    out: Path
    """The output folder ``results/<study>/``."""
    experiment_path: str
    """The Tune experiment (``storage/<study>``)."""
    errors: int
    """Trials that failed after all retries (a rerun retries them)."""


def trial_dirname(trial: Any) -> str:
    """Short trial folders (Tune's default spells out every parameter)."""
    return f"trial_{trial.trial_id}"


def progress_reporter(spec: StudySpec) -> tune.CLIReporter:
    """Status table every 30 s: the objective, safety, feasibility and the parameters."""
    return tune.CLIReporter(
        metric_columns={
            OBJECTIVE: "reward",
            "safety_mean": "safety",
            "feasible": "feasible",
            "duration_s": "s",
        },
        parameter_columns={p: p.rsplit(".", 1)[-1] for p in spec.params},
        max_report_frequency=30,
        sort_by_metric=False,
    )


def _is_uri(path: str) -> bool:
    return "://" in path


def experiment_location(spec: StudySpec) -> tuple[str, str]:
    """``(storage_path, experiment_path)``: local folders made absolute, URIs kept."""
    storage = spec.storage if _is_uri(spec.storage) else str(Path(spec.storage).resolve())
    return storage, f"{storage.rstrip('/')}/{spec.name}"


def _delete_tree(path: str) -> None:
    import pyarrow.fs as pafs

    fs, p = pafs.FileSystem.from_uri(path)
    if fs.get_file_info(p).type != pafs.FileType.NotFound:
        fs.delete_dir(p)


def _check_env(spec: StudySpec, demos: Path) -> None:
    env_id = read_meta(demos).env_id
    if env_id != spec.env.env_id:
        raise ValueError(
            f"{demos} holds {env_id} demonstrations but the study evaluates on "
            f"{spec.env.env_id}; set StudySpec(env=EnvConfig({env_id!r}))"
        )


def _check_resume(out: Path, identity: dict[str, Any], restoring: bool) -> None:
    """A resumed study must keep the trial count and the threshold (else ``--fresh``)."""
    path = out / "study.json"
    if restoring and path.exists():
        stored = json.loads(path.read_text())
        changed = [k for k, v in identity.items() if stored.get(k) != v]
        if changed:
            what = ", ".join(f"{k} {stored.get(k)} -> {identity[k]}" for k in changed)
            raise ValueError(
                f"the study at {out} was started with other settings ({what}); rerun with "
                f"the same ones to resume, or pass --fresh to start over"
            )
    write_text_atomic(path, json.dumps(identity, indent=2) + "\n")


@contextmanager
def _sigterm_as_sigint() -> Iterator[None]:
    """SIGTERM acts like Ctrl-C: during ``fit`` Tune checkpoints and returns (a rerun resumes),
    elsewhere it raises ``KeyboardInterrupt``."""

    def handler(signum: int, frame: Any) -> None:
        signal.raise_signal(signal.SIGINT)

    try:
        previous = signal.signal(signal.SIGTERM, handler)
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _records(grid: Any, params: Sequence[str]) -> list[dict[str, Any]]:
    """One record per trial (config, last result, status) from a ``ResultGrid``."""
    records = []
    for r in grid:
        m = dict(r.metrics or {})
        phase = m.get("phase", "")
        status = (
            "error"
            if r.error
            else {"evaluated": "done", "invalid": "invalid"}.get(phase, "unfinished")
        )
        rec = {k: m.get(k, math.nan) for k in TRIAL_METRICS}
        rec.update({k: r.config.get(k) for k in params})
        rec.update(
            trial_id=str(m.get("trial_id") or Path(r.path).name.removeprefix("trial_")),
            status=status,
            iterations=m.get("training_iteration", 0),
        )
        if r.error:
            rec["error"] = str(r.error).strip().splitlines()[-1][:300]
        records.append(rec)
    return records


class HistoryRecorder(tune.Callback):
    """Appends every reported result to a JSON-lines file as it arrives (in the driver).

    Tune's own ``result.json`` lost the rows before a failure when a trial was restored from
    its checkpoint (Ray 2.60, local storage), so the history is kept here. The callback is
    pickled with the experiment and keeps appending after ``Tuner.restore``.
    """

    def __init__(self, path: str) -> None:
        self.path = path

    def on_trial_result(self, iteration: int, trials: list, trial: Any, result: dict, **info):
        row = {k: v for k, v in flatten_dict(result).items() if not k.startswith("config/")}
        row["trial_id"] = trial.trial_id
        Path(self.path).parent.mkdir(parents=True, exist_ok=True)
        with open(self.path, "a") as f:
            f.write(json.dumps(row, default=str) + "\n")


def read_history(path: Path) -> pd.DataFrame:
    """The rows a :class:`HistoryRecorder` wrote (text columns without NaN, for Parquet)."""
    if not path.exists():
        return pd.DataFrame()
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    hist = pd.DataFrame(rows)
    for c in hist.columns:  # mixed text / NaN columns do not convert to Parquet
        if hist[c].dtype == object:
            hist[c] = hist[c].map(lambda v: "" if is_missing(v) else str(v))
    return hist


def run_study(
    spec: StudySpec,
    *,
    fresh: bool = False,
    command: str = "",
    progress: bool = True,
    callbacks: Sequence[Any] = (),
    trial_fn: Callable[[dict[str, Any], TrialJob], None] = run_trial,
) -> StudyOutcome:
    """Run (or resume) ``spec`` and write its outputs under ``spec.results / spec.name``.

    Args:
        fresh: delete a previous run of this study (Tune experiment and outputs) first.
        command: the command line, recorded in every table's metadata.
        progress: Tune's console progress (``verbose=1``) and evaluation bars.
        callbacks: extra Tune callbacks of a new run (a restored run keeps its own).
        trial_fn: the per-trial function ``(config, job)``; tests wrap it to inject faults.

    Returns:
        A :class:`StudyOutcome`; ``complete`` is False after an interruption.

    Raises:
        ValueError: a resumed study with another trial count or threshold, or demos of
            another task.
    """
    with _sigterm_as_sigint():
        return _run_study(spec, fresh, command, progress, callbacks, trial_fn)


def _run_study(
    spec: StudySpec,
    fresh: bool,
    command: str,
    progress: bool,
    callbacks: Sequence[Any],
    trial_fn: Callable[[dict[str, Any], TrialJob], None],
) -> StudyOutcome:
    from safe_bc.distributed.collect import ensure_demos

    os.environ.setdefault("TUNE_DISABLE_AUTO_CALLBACK_LOGGERS", "1")
    os.environ.setdefault("RAY_AIR_NEW_OUTPUT", "0")  # the terse status table of CLIReporter
    out = spec.results / spec.name
    storage, exp_path = experiment_location(spec)
    if fresh:
        _delete_tree(exp_path)
        for name in ("trials", "history", "final", "final_episodes"):
            (out / f"{name}.parquet").unlink(missing_ok=True)
        for name in ("best.json", "pareto.png", "study.json", HISTORY):
            (out / name).unlink(missing_ok=True)
    ensure_ray()
    demos_path = spec.demos.resolve()
    if not (demos_path / "dataset.json").exists():
        print(f"{spec.demos}: no demonstrations yet; collecting the default set")
        task = task_defaults(task_of(spec.env.env_id))
        ensure_demos(demos_path, task.collect_config(), progress=progress)
    _check_env(spec, demos_path)
    demos = cached_demos(str(demos_path))
    expert_safety = float(combined(demos.safety[demos.scored]).mean())
    threshold = expert_safety if spec.threshold is None else float(spec.threshold)
    d = thresholds(demos.costs, "max", valid=demos.scored)
    job = TrialJob(spec, str(demos_path), threshold, tuple(float(x) for x in d))

    restoring = tune.Tuner.can_restore(exp_path)
    if not restoring:  # a new experiment: rows of an older one do not belong to it
        (out / HISTORY).unlink(missing_ok=True)
    _check_resume(out, {"trials": spec.trials, "threshold": threshold}, restoring)
    resources = tune.PlacementGroupFactory(
        [{"CPU": spec.cpus_per_trial}] + [{"CPU": spec.cpus_per_worker}] * spec.rollout_workers
    )
    trainable = tune.with_resources(tune.with_parameters(trial_fn, job=job), resources)
    if restoring:
        print(f"resuming study {spec.name!r} from {exp_path}")
        tuner = tune.Tuner.restore(exp_path, trainable=trainable, resume_errored=True)
    else:
        tuner = tune.Tuner(
            trainable,
            tune_config=tune.TuneConfig(
                search_alg=make_searcher(spec),
                num_samples=spec.trials,
                max_concurrent_trials=spec.max_concurrent,
                reuse_actors=True,
                trial_dirname_creator=trial_dirname,
            ),
            run_config=tune.RunConfig(
                name=spec.name,
                storage_path=storage,
                failure_config=tune.FailureConfig(max_failures=spec.max_failures),
                callbacks=[
                    JsonLoggerCallback(),
                    CSVLoggerCallback(),
                    HistoryRecorder(str((out / HISTORY).resolve())),
                    *callbacks,
                ],
                progress_reporter=progress_reporter(spec),
                verbose=1 if progress else 0,
            ),
        )
    grid = tuner.fit()

    trials = trial_table(_records(grid, spec.params), spec.params)
    history = read_history(out / HISTORY)
    errors = int((trials["status"] == "error").sum())
    finished = int(trials["status"].isin(["done", "invalid", "error"]).sum())
    complete = finished >= spec.trials
    meta = {
        "command": command,
        "study": spec.summary(),
        "threshold": threshold,
        "expert_demo_safety_mean": expert_safety,
        "cost_thresholds": list(job.cost_thresholds),
        "seeds": {
            "train_seed": spec.base.bc.train.seed,
            "eval_seed": spec.eval_seed,
            "eval_seeds": heldout_seeds(spec.eval_seed, spec.eval_episodes),
            "final_seed": spec.final_seed,
            "sampler_seed": spec.sampler_seed,
        },
        "experiment_path": exp_path,
        "complete": complete,
        "provenance": provenance(),
    }
    write_table_atomic(out / "trials.parquet", trials, meta)
    write_table_atomic(out / "history.parquet", history, meta)
    winner = choose_winner(trials)
    plot_pareto(
        trials,
        threshold,
        out / "pareto.png",
        winner=winner.trial_id if winner and complete else None,
        title=f"{spec.name}: {finished}/{spec.trials} trials",
    )
    outcome = StudyOutcome(complete, trials, None, None, threshold, out, exp_path, errors)
    if not complete or winner is None:
        return outcome

    final = _reevaluate(spec, job, grid, winner, demos, meta, progress)
    return replace(outcome, winner=winner, final=final)


def _winner_model(grid: Any, trial_id: str) -> BCNet:
    for r in grid:
        if str((r.metrics or {}).get("trial_id")) == trial_id and r.checkpoint is not None:
            with r.checkpoint.as_directory() as d:
                return load_checkpoint(d)[0]
    raise RuntimeError(f"trial {trial_id} has no checkpoint to re-evaluate")


def _reevaluate(
    spec: StudySpec,
    job: TrialJob,
    grid: Any,
    winner: Winner,
    demos: Demonstrations,
    meta: dict[str, Any],
    progress: bool,
) -> pd.DataFrame:
    """Winner vs expert vs alpha = 0 on fresh held-out seeds; writes the final outputs."""
    threads = trial_threads(spec.cpus_per_trial)  # the baseline trains like a trial would
    win_cfg = spec.run_config({k: winner.row[k] for k in spec.params}, num_threads=threads)
    base_cfg = spec.baseline_config(win_cfg)
    if progress:
        print(f"training the alpha = 0 baseline ({spec.baseline}) for the re-evaluation")
    baseline, _ = train_run(demos, base_cfg, action_bounds=_bounds(spec))
    sources = {
        "winner": NetSource.from_model(_winner_model(grid, winner.trial_id), win_cfg.bc),
        "bc_alpha0": NetSource.from_model(baseline.model, base_cfg.bc),
        "expert": ExpertSource(stored_expert_config(Path(job.demos))),
    }
    config = EvalConfig(
        episodes=spec.final_episodes,
        workers=spec.final_workers,
        seed=spec.final_seed,
        env=spec.env,
        max_steps=spec.max_steps,
        eps=spec.critical_eps,
    )
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)  # in-process evaluation: 2 threads ran ~5x slower here
    try:
        episodes, _ = evaluate_policies(
            sources, config, thresholds=np.asarray(job.cost_thresholds), progress=progress
        )
    finally:
        torch.set_num_threads(previous)
    final = summarize(episodes, ["policy"], FINAL_METRICS, group=None, seed=spec.final_seed)
    final["feasible"] = final["safety_mean"] >= job.threshold
    final["threshold"] = job.threshold
    order = {k: i for i, k in enumerate(sources)}
    final = final.sort_values("policy", key=lambda c: c.map(order)).reset_index(drop=True)
    out = spec.results / spec.name
    final_meta = {
        **meta,
        "final_seeds": heldout_seeds(spec.final_seed, spec.final_episodes),
        "winner": winner.trial_id,
        "winner_config": win_cfg.to_dict(),
        "baseline_config": base_cfg.to_dict(),
    }
    write_table_atomic(out / "final.parquet", final, final_meta)
    write_table_atomic(out / "final_episodes.parquet", episodes, final_meta)
    best = {
        "study": spec.name,
        "trial_id": winner.trial_id,
        "feasible": winner.feasible,
        "message": winner.message,
        "threshold": job.threshold,
        "params": {k: winner.row[k] for k in spec.params},
        "trial_metrics": {k: winner.row.get(k) for k in TRIAL_METRICS},
        "run_config": win_cfg.to_dict(),
        "baseline": spec.baseline,
        "baseline_config": base_cfg.to_dict(),
        "final": final.to_dict(orient="records"),
        "final_seeds": final_meta["final_seeds"],
        "command": meta["command"],
        "provenance": meta["provenance"],
    }
    text = json.dumps(best, indent=2, default=_json_default, allow_nan=True)
    write_text_atomic(out / "best.json", text + "\n")
    return final


def _json_default(v: Any) -> Any:
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, Path):
        return str(v)
    return str(v)


def format_outcome(outcome: StudyOutcome, params: Sequence[str]) -> str:
    """The closing summary printed by ``safe-bc tune``."""
    t = outcome.trials
    lines = [
        f"study {outcome.out.name}: {len(t)} trials, {int(t['feasible'].sum())} feasible "
        f"(safety mean >= {outcome.threshold:.2f}), {outcome.errors} failed",
        summary_lines(t, params),
    ]
    if not outcome.complete:
        lines.append("study incomplete: run the same command again to resume")
    elif outcome.winner is not None:
        lines.append(outcome.winner.message)
    else:
        lines.append("no trial finished its evaluation")
    if outcome.final is not None:
        cols = ["policy", "reward", "reward_lo", "reward_hi", "safety_mean", "safety_mean_lo",
                "safety_mean_hi", "offroad_steps", "feasible"]  # fmt: skip
        lines.append("re-evaluation on fresh held-out seeds (95% bootstrap CIs):")
        lines.append(outcome.final[cols].to_string(index=False, float_format=lambda x: f"{x:.2f}"))
    lines.append(f"outputs in {outcome.out}/")
    return "\n".join(lines)
