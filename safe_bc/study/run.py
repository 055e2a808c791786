"""Running a ``StudySpec`` on Ray Tune + Optuna: constrained search, resumable, re-evaluated.

:func:`run_study` reads as plan -> run -> report. The plan is pure and made once
(:func:`safe_bc.study.plan.plan_study`: paths, the Tune experiment, the Optuna copy, what a
resume compares); the run's phases receive the plan and the records of the phases before:
:func:`_start` (outputs, Ray, the demonstrations, the bars and the trials' job, the resume
check), :func:`_tune` (the Tuner, new or restored, and its fit), then
:func:`_final_and_certificate` for a complete tuning with a winner. The report writes
``trials.parquet``, ``history.parquet`` and ``pareto.png`` (:func:`_report_trials`), the
final phase's ``final.parquet``, ``final_episodes.parquet``, ``final_paired.parquet`` and
``best.json`` (:func:`_write_final`), the certificate and recommender (:func:`deliver`), the
time table and the finished mark. The pieces live in their own modules: the searcher,
scheduler and Optuna copy (``study/search.py``), one trial (``study/trial.py``)
and the final phase (``study/final.py``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import json
import math
import os
import pickle
import shutil
import signal
import sys
import time
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from ray import tune
from ray.tune.logger import CSVLoggerCallback, JsonLoggerCallback, TBXLoggerCallback
from ray.tune.schedulers import FIFOScheduler, TrialScheduler
from ray.tune.utils import flatten_dict

from safe_bc.bc import BCConfig, CheckpointError, load_checkpoint
from safe_bc.bc.net import BCNet
from safe_bc.data.atomic import write_json_atomic, write_text_atomic
from safe_bc.data.provenance import (
    check_result_write,
    committed_unchanged,
    provenance,
    repo_relative,
)
from safe_bc.data.store import (
    DatasetError,
    DatasetMeta,
    dataset_record,
    delete_storage_tree,
    read_demonstrations,
    read_meta,
    read_table,
    storage_folders,
    write_table_atomic,
    write_tables_atomic,
)
from safe_bc.distributed.runtime import cluster_cpus, ensure_ray
from safe_bc.plots import plot_pareto
from safe_bc.study.console import (
    FULL_DISK,
    TrialLines,
    is_full_disk,
    progress_reporter,
    quiet_full_disk,
    quiet_logs,
    quiet_stop,
)
from safe_bc.study.final import FinalOutcome, final_phase
from safe_bc.study.final_store import STORE, FinalStore
from safe_bc.study.plan import (
    StudyPlan,
    constraint_bars,
    is_uri,
    plan_study,
    run_identity,
    trials_meta,
)
from safe_bc.study.resume import (
    ResumeRefused,
    check_published,
    check_resume,
    claim_experiment,
    history_events,
    identity_problem,
    install_atomic_upload,
    take_failed_copy,
    with_more_trials,
)
from safe_bc.study.search import (
    NUMBER,
    ConstrainedOptunaSearch,
    SpaceSampler,
    check_optuna_copy,
    load_searcher,
    make_scheduler,
    make_searcher,
    mark_final_winner,
    raise_trial_count,
    take_copy_seconds,
)
from safe_bc.study.spec import (
    ConstraintBars,
    StudySpec,
    Winner,
    choose_candidates,
    choose_winner,
    is_missing,
    subset_warnings,
    summary_lines,
    trial_metrics,
    trial_table,
)
from safe_bc.study.stop import (
    _fit_stopped,
    _reinstall_signals,
    _stop_signals,
)
from safe_bc.study.timing import COPY, TOTAL, timing_lines, timing_markdown, timing_table
from safe_bc.study.trial import (
    TrialJob,
    checkpoint_problem,
    run_trial,
    stored_checkpoint,
)
from safe_bc.study.trial_curves import (
    BOARD,
    TrialCurves,
    final_run_name,
    run_names,
    write_board,
    write_final_curve,
)
from safe_bc.tasks import check_frames_renderer, frames_renderer, task_defaults, task_of
from safe_bc.tasks.env_config import EnvConfig

__all__ = [
    "ConstrainedOptunaSearch",
    "SpaceSampler",
    "StudyOutcome",
    "TrialJob",
    "format_outcome",
    "load_searcher",
    "make_searcher",
    "run_study",
    "run_trial",
]


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
    """The best trial on the trials' own evaluation (``None`` while incomplete or when nothing
    finished); the study's winner is ``final.winner``, chosen on the re-evaluation."""
    final: FinalOutcome | None
    """The final phase (``final.parquet``), or ``None``."""
    threshold: float
    """The safety threshold used."""
    out: Path
    """The output folder ``results/<study>/``."""
    experiment_path: str
    """The Tune experiment (``storage/<study>``)."""
    errors: int
    """Trials that failed after all retries (a rerun retries them)."""
    stopped_by: int = 0
    """The signal that stopped Tune's run of the trials (0: none; SIGINT is seen as an
    incomplete study, SIGTERM is recorded here)."""
    timing: pd.DataFrame | None = None
    """Where the study's time went (``timing.parquet``, :func:`safe_bc.study.timing.timing_table`);
    ``None`` when not recorded (a study finished before timings were)."""
    certificate: dict[str, Any] | None = None
    """The recommender's certificate (:func:`safe_bc.study.certify.certify`), ``None``
    without a certification."""
    unit: str = "episodes"
    """What the study's task calls its episodes (``TaskSpec.episodes_name``: ``tracks``,
    ``patients``), the summary's word for them."""

    @property
    def exit_code(self) -> int:
        """``safe-bc tune``'s exit status: 143 after SIGTERM, 130 when incomplete (Ctrl-C),
        1 when trials failed or none finished, 3 when no final candidate met every constraint
        (its recommender, if written, is marked uncertified), else 0."""
        if self.stopped_by:
            return 128 + self.stopped_by
        if not self.complete:
            return 130
        if self.errors or self.winner is None:
            return 1
        return 3 if self.final is not None and not self.final.feasible else 0


def trial_dirname(trial: Any) -> str:
    """Short trial folders (Tune's default spells out every parameter)."""
    return f"trial_{trial.trial_id}"


def _check_env(env: EnvConfig, collected: EnvConfig, demos: Path) -> None:
    """The demonstrations at ``demos``, collected on ``collected`` (the set is refused unless it
    is the one that collection makes), must be of the study's env."""
    if collected.env_id != env.env_id:
        raise ValueError(
            f"{demos} holds {collected.env_id} demonstrations but the study evaluates on "
            f"{env.env_id}; set StudySpec(env=EnvConfig({collected.env_id!r}))"
        )
    warning = check_frames_renderer(frames_renderer(collected), env, demos)
    if warning:
        print(f"warning: {warning}", file=sys.stderr)


def _check_validation_demos(validation: Path, demos: Path, meta: DatasetMeta) -> None:
    """The study's validation set must be another set of the same task and observations as
    the demonstrations at ``demos`` (metadata ``meta``)."""
    if not (validation / "dataset.json").exists():
        raise ValueError(f"validation_demos {validation}: no demonstration set there")
    a = read_meta(validation)
    if a.env_id != meta.env_id or tuple(a.obs_shape) != tuple(meta.obs_shape):
        raise ValueError(
            f"validation_demos {validation} holds {a.env_id} {tuple(a.obs_shape)} observations, "
            f"the study's demonstrations {meta.env_id} {tuple(meta.obs_shape)}"
        )
    if validation == demos:
        raise ValueError("validation_demos is the training set itself; collect another one")


def _check_resume(out: Path, identity: dict[str, Any], restoring: bool, exp_path: str) -> int:
    """A resumed study must keep the threshold, limits, batch size and demonstrations (else
    ``--fresh``); its trial count may grow (never shrink): the experiment's saved search state
    is raised to it (:func:`raise_trial_count`). Returns the number of trials added."""
    path = out / "study.json"
    added = 0
    if restoring and path.exists():
        stored = json.loads(path.read_text())
        if isinstance(stored.get("experiment_path"), str):  # absolute or relative: one folder
            stored["experiment_path"] = repo_relative(stored["experiment_path"])
        if "settings" in stored and "settings" in identity:  # the count is checked as trials
            stored["settings"] = with_more_trials(stored["settings"], identity["settings"])
        changed = [k for k, v in identity.items() if k in stored and stored.get(k) != v]
        more = isinstance(stored.get("trials"), int) and identity["trials"] > stored["trials"]
        if changed == ["trials"] and more:
            if is_uri(exp_path):
                raise ValueError(
                    f"adding trials to a study needs a local --storage (the study's Tune "
                    f"experiment is at {exp_path})"
                )
            raise_trial_count(exp_path, identity["trials"])
            added = identity["trials"] - stored["trials"]
        elif changed:
            what = ", ".join(
                identity_problem(stored[k], identity[k])
                if k == "settings"
                else f"{k} {stored.get(k)} -> {identity[k]}"
                for k in changed
            )
            raise ValueError(
                f"the study at {out} was started with other settings ({what}); rerun with "
                f"the same ones to resume (more trials are allowed), or pass --fresh to start over"
            )
    write_json_atomic(path, identity)
    return added


def _os_error_in(e: BaseException) -> OSError | None:
    """The ``OSError`` behind ``e`` (itself, or in its causes), reworded to say what a rerun
    does; ``None`` when there is none."""
    seen = set()
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if getattr(e, "reworded", False):
            return e  # already says what a rerun does
        if isinstance(e, OSError):
            detail = e.strerror or " ".join(str(e).split()) or type(e).__name__
            error = OSError(
                e.errno,
                f"{detail}; the study stopped with its state saved: fix this (e.g. free disk "
                "space) and rerun the same command to resume",
                e.filename,
            )
            error.reworded = True  # type: ignore[attr-defined]
            return error
        e = e.__cause__ or e.__context__
    return None


def _records(grid: Any, params: Sequence[str]) -> list[dict[str, Any]]:
    """One record per trial (config, last result, status) from a ``ResultGrid``."""
    records = []
    for r in grid:
        m = dict(r.metrics or {})
        config = r.config or {}  # None for a trial stopped right after it was suggested
        phase = m.get("phase", "")
        status = (
            "error"
            if r.error
            else {"evaluated": "done", "invalid": "invalid", "screened": "stopped"}.get(
                phase, "unfinished"
            )
        )
        rec = {k: m.get(k, math.nan) for k in trial_metrics()}
        rec.update({k: config.get(k) for k in params})
        rec.update(
            trial_id=str(m.get("trial_id") or Path(r.path or "").name.removeprefix("trial_")),
            trial_number=config.get(NUMBER),
            status=status,
            iterations=m.get("training_iteration", 0),
        )
        if r.error:
            rec["error"] = str(r.error).strip().splitlines()[-1][:300]
        records.append(rec)
    if records and all(r["trial_number"] is not None for r in records):
        records.sort(key=lambda r: r["trial_number"])  # suggestion order
    return records


def _study_history(history: pd.DataFrame, trials: pd.DataFrame) -> tuple[pd.DataFrame, list[str]]:
    """The history rows of the trials in ``trials`` (every trial Tune knows; one per trial and
    phase), and the ids of the trials whose rows are set aside: trials that a driver killed
    before Tune saved them had started (the restored experiment does not know them and ran
    others in their place)."""
    if history.empty or "trial_id" not in history:
        return history, []
    known = history["trial_id"].isin(set(trials["trial_id"]))
    lost = sorted(set(history.loc[~known, "trial_id"]))
    kept = history[known]
    if "phase" in kept:  # a round reported again by a restarted trial (from its stored
        # episodes, :func:`safe_bc.study.trial.stored_round`) counts once: the last report
        kept = kept[~kept.duplicated(["trial_id", "phase"], keep="last")]
    # in trial order, each trial's reports in its order (not in the order concurrent trials'
    # reports happened to arrive), so the same study gives the same table
    numbers = trials["trial_number"] if "trial_number" in trials else range(len(trials))
    number = kept["trial_id"].map(dict(zip(trials["trial_id"], numbers, strict=True)))
    order = [number] + ([kept["training_iteration"]] if "training_iteration" in kept else [])
    keys = pd.DataFrame({f"k{i}": k.to_numpy() for i, k in enumerate(order)}, index=kept.index)
    kept = kept.loc[keys.sort_values(list(keys.columns), kind="stable").index]
    return kept.reset_index(drop=True), lost


def _remove_orphan_trial_dirs(exp_path: str, known: set[str]) -> list[str]:
    """Delete the ``trial_<id>`` folders of trials the experiment does not know (see
    :func:`_study_history`) and return their ids."""
    fs, folders = storage_folders(exp_path, prefix="trial_")
    orphans = []
    for path, name in folders:
        tid = name.removeprefix("trial_")
        if tid not in known:
            fs.delete_dir(path)
            orphans.append(tid)
    return sorted(orphans)


def append_lines(path: str | Path, rows: Sequence[dict[str, Any]]) -> None:
    """Append ``rows`` to the JSON-lines file ``path``, whole lines or nothing: a write that
    fails (a full disk) is cut back to the file's size before it, so no line is left
    half-written."""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    data = "".join(json.dumps(row, default=str) + "\n" for row in rows).encode()
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        size = os.fstat(fd).st_size
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view) :]
        except OSError:
            with contextlib.suppress(OSError):
                os.ftruncate(fd, size)
            raise
    finally:
        os.close(fd)


class HistoryRecorder(tune.Callback):
    """Appends every reported result to a JSON-lines file as it arrives (in the driver), and a
    line ``{"trial_id", "event": "complete" | "error", "timestamp"}`` when a trial has ended
    and Tune has saved the experiment state that says so (:class:`SaveOnTrialEnd`: those are
    written at the end of the step, after the save).

    Tune's own ``result.json`` lost the rows before a failure when a trial was restored from
    its checkpoint (Ray 2.60, local storage), so the history is kept here. The callback is
    pickled with the experiment and keeps appending after ``Tuner.restore``.
    """

    def __init__(self, path: str) -> None:
        self.path = path
        self._ended: list[tuple[str, str]] = []

    def _append(self, rows: list[dict[str, Any]]) -> None:
        append_lines(self.path, rows)

    def on_trial_result(self, iteration: int, trials: list, trial: Any, result: dict, **info):
        row = {k: v for k, v in flatten_dict(result).items() if not k.startswith("config/")}
        row["trial_id"] = trial.trial_id
        self._append([row])

    def _end(self, trial: Any, event: str) -> None:
        self.__dict__.setdefault("_ended", []).append((trial.trial_id, event))

    def on_trial_complete(self, iteration: int, trials: list, trial: Any, **info) -> None:
        self._end(trial, "complete")

    def on_trial_recover(self, iteration: int, trials: list, trial: Any, **info) -> None:
        _stop_on_full_disk(trial)  # before Tune spends the trial's retries on it

    def on_trial_error(self, iteration: int, trials: list, trial: Any, **info) -> None:
        _stop_on_full_disk(trial)  # not an error of the trial: the rerun runs it again
        self._end(trial, "error")

    def on_step_end(self, iteration: int, trials: list, **info) -> None:
        failed = take_failed_copy()
        if failed is not None:  # Tune's state did not reach the storage: no trial's end may be
            raise failed  # recorded as saved, and the study stops (one line) to be rerun
        ended = self.__dict__.get("_ended")
        if ended:  # Tune calls this after the step's save of the experiment state
            now = time.time()
            self._append([{"trial_id": t, "event": e, "timestamp": now} for t, e in ended])
            ended.clear()


def _stop_on_full_disk(trial: Any) -> None:
    """Stop the study with an ``OSError`` (one line at the CLI, exit 2) when ``trial`` failed
    because its storage is full: retrying it would fail the same way, and recording it as
    failed would drop its finished work from the rerun."""
    try:  # the driver's own copy of the trial's errors (the storage's may not be written)
        error = Path(trial.error_file).read_text().rsplit("Failure # ", 1)[-1]
    except (OSError, TypeError):
        error = ""
    if is_full_disk(error):
        raise OSError(errno.ENOSPC, FULL_DISK, str(getattr(trial, "path", "") or ""))


def read_history(path: Path) -> pd.DataFrame:
    """The results a :class:`HistoryRecorder` wrote (text columns without NaN, for Parquet); a
    line cut short by a killed driver is skipped."""
    if not path.exists():
        return pd.DataFrame()
    rows = []
    for line in path.read_text().splitlines():
        try:
            row = json.loads(line)
        except json.JSONDecodeError:
            continue
        if "event" not in row:  # a result, not the end of a trial
            rows.append(row)
    hist = pd.DataFrame(rows)
    for c in hist.columns:  # mixed text / NaN columns do not convert to Parquet
        if hist[c].dtype == object:
            hist[c] = hist[c].map(lambda v: "" if is_missing(v) else str(v))
    return hist


# --- where the time goes ------------------------------------------------------------------------

TIMING_LOG = "timing.jsonl"
"""The driver's timed pieces, every run of the study (``timing.parquet`` is made from it)."""
TIMING = "timing.parquet"
"""Where the study's time went (:func:`safe_bc.study.timing.timing_table`); ``timing.md`` beside
it."""


class RunningMeter(tune.Callback):
    """The most trials Tune had running at once during this driver run (counted at the end of
    every step of the tuning loop): the concurrency reached, for the time table."""

    def __init__(self) -> None:
        self.most = 0

    def on_step_end(self, iteration: int, trials: list, **info: Any) -> None:
        running = sum(1 for t in trials if t.status == "RUNNING")
        self.most = max(self.__dict__.get("most", 0), running)


def _running_meter(tuner: tune.Tuner) -> RunningMeter:
    """The tuner's :class:`RunningMeter` (a restored experiment keeps its pickled callbacks:
    the one it has, else a new one added), reset for this run."""
    run_config = tuner._local_tuner._run_config
    callbacks = list(run_config.callbacks or [])
    meter = next((c for c in callbacks if isinstance(c, RunningMeter)), None)
    if meter is None:
        meter = RunningMeter()
        run_config.callbacks = [*callbacks, meter]
    meter.most = 0
    return meter


class StudyClock:
    """The driver's timings of one run: each piece appended to :data:`TIMING_LOG` as it ends
    (kept in memory until :meth:`open`, which says whether the log belongs to an older,
    replaced experiment)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.run = f"{time.strftime('%Y%m%dT%H%M%S')}-{uuid.uuid4().hex[:8]}"
        self.started = time.perf_counter()
        self.mark = self.started
        self.pending: list[dict[str, Any]] = []
        self.live = False

    def add(self, phase: str, seconds: float, **extra: Any) -> None:
        """Record ``seconds`` of ``phase``."""
        self.pending.append({"run": self.run, "phase": phase, "seconds": seconds, **extra})
        if self.live:
            append_lines(self.path, self.pending)
            self.pending.clear()

    def lap(self, phase: str, **extra: Any) -> float:
        """Record the time since the last lap (or the start) as ``phase``; its seconds."""
        now = time.perf_counter()
        seconds, self.mark = now - self.mark, now
        self.add(phase, seconds, **extra)
        return seconds

    def skip(self) -> None:
        """Start the next lap now (what ran since the last one counts as ``other``)."""
        self.mark = time.perf_counter()

    def open(self, new_experiment: bool) -> None:
        """Start writing the log (a new experiment first deletes an older one's)."""
        if new_experiment:
            self.path.unlink(missing_ok=True)
        self.live = True
        if self.pending:
            append_lines(self.path, self.pending)
            self.pending.clear()

    def close(self) -> None:
        """Record this run's whole wall-clock."""
        self.add(TOTAL, time.perf_counter() - self.started)


def read_timing_log(path: Path) -> list[dict[str, Any]]:
    """The records of :data:`TIMING_LOG` (a line cut short by a killed driver is skipped)."""
    if not path.exists():
        return []
    rows = []
    for line in path.read_text().splitlines():
        try:
            row = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(row, dict) and "phase" in row and "seconds" in row:
            rows.append(row)
    return rows


def write_timing(out: Path, trials: pd.DataFrame, meta: dict[str, Any]) -> pd.DataFrame:
    """Write ``timing.parquet`` and ``timing.md`` from :data:`TIMING_LOG` and the trial table
    (``meta``: the command and the provenance) and return the table."""
    records = read_timing_log(out / TIMING_LOG)
    table = timing_table(records, trials)
    runs = sorted({str(r.get("run", "")) for r in records})
    tmeta = {
        "command": meta.get("command", ""),
        "study": meta.get("study", {}),
        "driver_runs": runs,
        "inputs": meta.get("inputs", {}),
        "source": f"{TIMING_LOG} (the driver's pieces) and trials.parquet (the trials' seconds)",
        "provenance": meta.get("provenance") or provenance(),
    }
    write_table_atomic(out / TIMING, table, tmeta)
    prov = tmeta["provenance"]
    note = (
        f"Made by `{tmeta['command'] or 'safe-bc tune'}` over {len(runs)} driver run(s); "
        f"revision {str(prov.get('git_revision', ''))[:12]}, {prov.get('cpu_model', '')} "
        f"({prov.get('cpus', '?')} CPUs), {prov.get('created_utc', '')}. "
        f"Made from `{TIMING_LOG}` and `trials.parquet`."
    )
    write_text_atomic(out / "timing.md", timing_markdown(table, note))
    return table


# --- persisting the experiment state after every trial -----------------------------------------


class SaveOnTrialEnd(TrialScheduler):
    """The study's scheduler, wrapped: Tune saves the experiment state (every trial's status and
    last result, the searcher's state, the callbacks) at the end of the step in which a trial
    completes or fails, and waits for it to reach the storage.

    Ray 2.60 saves that state only at the first step, then at most every ``max(10 s, 19 x the
    last save's duration)`` (``TUNE_GLOBAL_CHECKPOINT_S`` unset: ``"auto"``) and at the end of
    ``fit`` (also on Ctrl-C): a driver killed in between restored an older state and ran the
    trials finished since again. Tune hands schedulers the controller in ``on_trial_complete``
    and ``on_trial_error``; this sets the flag with which Tune itself forces a save
    (``CheckpointConfig(num_to_keep)``); :func:`check_persistence_api` checks it exists.
    """

    def __init__(self, inner: TrialScheduler) -> None:
        super().__init__()
        self.inner = inner

    @property
    def metric(self) -> str | None:
        return self.inner.metric

    @property
    def supports_buffered_results(self) -> bool:
        return self.inner.supports_buffered_results

    def set_search_properties(self, metric: str | None, mode: str | None, **spec: Any) -> bool:
        return self.inner.set_search_properties(metric, mode, **spec)

    def on_trial_add(self, tune_controller: Any, trial: Any) -> None:
        self.inner.on_trial_add(tune_controller, trial)

    def on_trial_error(self, tune_controller: Any, trial: Any) -> None:
        self.inner.on_trial_error(tune_controller, trial)
        _save_at_step_end(tune_controller)

    def on_trial_result(self, tune_controller: Any, trial: Any, result: dict) -> str:
        return self.inner.on_trial_result(tune_controller, trial, result)

    def on_trial_complete(self, tune_controller: Any, trial: Any, result: dict) -> None:
        self.inner.on_trial_complete(tune_controller, trial, result)
        _save_at_step_end(tune_controller)

    def on_trial_remove(self, tune_controller: Any, trial: Any) -> None:
        self.inner.on_trial_remove(tune_controller, trial)

    def choose_trial_to_run(self, tune_controller: Any) -> Any:
        return self.inner.choose_trial_to_run(tune_controller)

    def debug_string(self) -> str:
        return self.inner.debug_string()

    def save(self, checkpoint_path: str) -> None:
        self.inner.save(checkpoint_path)

    def restore(self, checkpoint_path: str) -> None:
        self.inner.restore(checkpoint_path)


def _save_at_step_end(tune_controller: Any) -> None:
    """Make the save at the end of Tune's current step a forced, waited-for one (after the trial's
    new status is set: Tune calls the scheduler first).

    Tune's forced save waits for the *previous* copy to the storage, then starts its own in a
    thread; a forced save here also waits for its own copy, so that when the step's callbacks
    run (:class:`HistoryRecorder` writes the trial's end then) the storage holds the state that
    says so: a driver killed after that line restores a state that knows the trial."""
    controller = getattr(tune_controller, "_tune_controller", tune_controller)  # unwrapped
    manager = getattr(controller, "_checkpoint_manager", None)
    if manager is None:
        return
    manager._should_force_sync_up = True
    if not manager.__dict__.get("_safe_bc_waits"):
        original = manager.sync_up_experiment_state

        def sync_up(save_fn: Callable[[], None], force: bool = False, wait: bool = False) -> None:
            forced = force or manager._should_force_sync_up
            original(save_fn=save_fn, force=force, wait=wait or forced)

        manager.sync_up_experiment_state = sync_up
        manager._safe_bc_waits = True


def check_persistence_api() -> None:
    """Raise ``RuntimeError`` naming what :class:`SaveOnTrialEnd` and :func:`_save_every_trial`
    rely on (Ray 2.60 internals) when the installed Ray lacks it."""
    from ray.tune.execution.experiment_state import _ExperimentCheckpointManager
    from ray.tune.execution.tune_controller import TuneController
    from ray.tune.impl.tuner_internal import TunerInternal

    uses = {
        "TuneController._checkpoint_manager": "_checkpoint_manager"
        in TuneController.__init__.__code__.co_names,
        "_ExperimentCheckpointManager._should_force_sync_up": "_should_force_sync_up"
        in _ExperimentCheckpointManager.sync_up_experiment_state.__code__.co_names,
        "_ExperimentCheckpointManager.sync_up_experiment_state(save_fn, force, wait)": (
            _ExperimentCheckpointManager.sync_up_experiment_state.__code__.co_varnames[:4]
            == ("self", "save_fn", "force", "wait")
        ),
        "TunerInternal._tune_config": "_tune_config" in TunerInternal.__init__.__code__.co_names,
        "TunerInternal._run_config": "_run_config" in TunerInternal.__init__.__code__.co_names,
        "Tuner._local_tuner": "_local_tuner" in tune.Tuner.__annotations__,
    }
    missing = [name for name, ok in uses.items() if not ok]
    if missing:
        raise RuntimeError(
            f"ray.tune no longer has {', '.join(missing)}; safe_bc's saving of the experiment "
            "state after every trial (study/run.py) needs updating for this Ray version"
        )


def _save_every_trial(tuner: tune.Tuner) -> None:
    """A restored experiment started before :class:`SaveOnTrialEnd` existed gets it too (and
    the save after every trial checkpoint): Tune restores both from its ``tuner.pkl``."""
    internal = tuner._local_tuner
    config, run_config = internal._tune_config, internal._run_config
    if not isinstance(config.scheduler, SaveOnTrialEnd):
        config.scheduler = SaveOnTrialEnd(config.scheduler or FIFOScheduler())
    if run_config.checkpoint_config.num_to_keep is None:
        run_config.checkpoint_config = replace(run_config.checkpoint_config, num_to_keep=1)


def run_study(
    spec: StudySpec,
    *,
    fresh: bool = False,
    command: str = "",
    progress: bool = True,
    callbacks: Sequence[Any] = (),
    trial_fn: Callable[[dict[str, Any], TrialJob], None] = run_trial,
    final: bool = True,
    verbose: bool = False,
) -> StudyOutcome:
    """Run (or resume) ``spec`` and write its outputs under ``spec.results / spec.name``.

    Args:
        fresh: delete a previous run of this study (Tune experiment and outputs) first.
        command: the command line, recorded in every table's metadata.
        progress: a line per finished trial and the final phase's progress.
        verbose: Tune's own status table every 30 s instead of the trial lines.
        callbacks: extra Tune callbacks (e.g. a tracker's); a restored run keeps its own and
            adds those of a kind it lacks.
        trial_fn: the per-trial function ``(config, job)``; tests wrap it to inject faults.
        final: False stops after the trial tables and the time table (no final phase, the
            study is not marked finished): for measuring the tuning loop alone.

    Returns:
        A :class:`StudyOutcome`; ``complete`` is False after an interruption.

    Raises:
        ValueError: a resumed study with another trial count or threshold, or demos of
            another task.
    """
    plan = plan_study(spec, fresh=fresh, command=command, final=final)
    options = DriverOptions(progress, verbose, tuple(callbacks), trial_fn)
    with _stop_signals() as stop:
        try:
            outcome = _run_study(plan, options)
        except OSError as e:  # one line at the CLI, saying what a rerun does
            raise _os_error_in(e) from None
        return replace(outcome, stopped_by=stop.signum) if stop.signum else outcome


@dataclass(frozen=True)
class DriverOptions:
    """How this driver run talks and what it hands Tune (not part of the plan: a rerun may
    change it)."""

    progress: bool
    """A line per finished trial and the final phase's progress."""
    verbose: bool
    """Tune's own status table instead of the trial lines."""
    callbacks: tuple[Any, ...]
    """Extra Tune callbacks (a restored run adds those of a kind it lacks)."""
    trial_fn: Callable[[dict[str, Any], TrialJob], None]
    """The per-trial function ``(config, job)``."""


@dataclass(frozen=True)
class StudyStart:
    """What the set-up of a run found: the demonstrations, the bars, the trials' job and
    whether Tune resumes an experiment."""

    cpus: float
    """The cluster's CPUs."""
    demos: Any
    """The demonstrations (:class:`safe_bc.data.demos.Demonstrations`)."""
    inputs: dict[str, Any]
    """The inputs' record (the demonstrations' identity) stored with every table."""
    threshold: float
    """The safety threshold."""
    limits: ConstraintBars
    """The bars every trial is held to."""
    job: TrialJob
    """What every trial receives."""
    restoring: bool
    """Tune restores an experiment."""
    added: int
    """Trials added to a restored experiment."""


@dataclass(frozen=True)
class TrialReport:
    """The trial tables as written, and what they decide."""

    trials: pd.DataFrame
    """The trial table (``trials.parquet``)."""
    meta: dict[str, Any]
    """Its metadata (extended by every later table)."""
    complete: bool
    """Every trial finished."""
    errors: int
    """Trials that failed after all retries."""
    winner: Winner | None
    """The best trial on the trials' own evaluation."""
    candidates: pd.DataFrame
    """The final phase's candidates (:func:`safe_bc.study.spec.choose_candidates`)."""
    title: str
    """``pareto.png``'s title."""
    history: pd.DataFrame = dataclasses.field(default_factory=pd.DataFrame)
    """The report history (``history.parquet``)."""


def _run_study(plan: StudyPlan, options: DriverOptions) -> StudyOutcome:
    """The plan run and reported: a study finished before only reads its tables back; else
    set up, tune, write the trial tables, then (for a complete tuning with a winner) the final
    phase, the certificate and the finished mark."""
    done = None if plan.fresh else finished_outcome(plan)
    if done is not None:
        print(
            f"study {plan.spec.name!r} finished before with these settings: its result, read "
            f"from {done.out}/ (pass --fresh to run it again from scratch)"
        )
        return done
    clock = StudyClock(plan.out / TIMING_LOG)
    start = _start(plan, clock, options)
    grid, stopped = _tune(plan, start, clock, options)
    report = _report_trials(plan, start, grid)
    clock.lap("trial_tables")
    outcome = StudyOutcome(
        report.complete, report.trials, None, None, start.threshold, plan.out, plan.exp_path,
        report.errors, unit=plan.spec.task().episodes_name,
    )  # fmt: skip
    if not report.complete or report.winner is None or stopped or not plan.final:
        clock.close()
        timing = write_timing(plan.out, report.trials, report.meta)
        return replace(outcome, stopped_by=stopped, timing=timing)
    final, certificate, meta = _final_and_certificate(plan, start, grid, report, clock, options)
    clock.close()
    timing = write_timing(plan.out, report.trials, meta)
    check_optuna_copy(plan, plan.exp_path)  # never a finished claim over a broken copy
    write_json_atomic(plan.out / FINISHED, plan.finished, default=str)
    return replace(
        outcome, winner=report.winner, final=final, timing=timing, certificate=certificate
    )


# --- the run ------------------------------------------------------------------------------------


def _start(plan: StudyPlan, clock: StudyClock, options: DriverOptions) -> StudyStart:
    """The outputs made ready (emptied with ``fresh``, else the resume checked), Ray started,
    the demonstrations read (collected when missing), the bars and the trials' job, and the
    run's identity recorded (``study.json``)."""
    _prepare_outputs(plan, options.verbose)
    clock.skip()
    ensure_ray()
    clock.lap("ray_start")
    cpus = cluster_cpus()
    _reinstall_signals()  # ray.init replaced the SIGTERM handler
    demos, inputs = _study_demos(plan, options.progress)
    clock.lap("demos")
    threshold, limits = constraint_bars(plan.spec, demos.safety_mean, demos.dim_safety_means())
    cost_limits = tuple(float(x) for x in demos.limits)
    identity = run_identity(plan, threshold, cost_limits, inputs)
    for line in subset_warnings(plan.spec, demos):
        print(f"warning: {line}")
    validation = None if plan.validation is None else str(plan.validation)
    job = TrialJob(plan.spec, str(plan.demos), limits, cost_limits, validation)
    restoring = tune.Tuner.can_restore(plan.exp_path)
    if not restoring:  # a new experiment: rows of an older one do not belong to it
        (plan.out / HISTORY).unlink(missing_ok=True)
        (plan.out / FINISHED).unlink(missing_ok=True)
    clock.open(new_experiment=not restoring)
    added = _check_resume(plan.out, identity, restoring, plan.exp_path)
    if plan.local:
        claim_experiment(plan.exp_path, plan.out)
    return StudyStart(cpus, demos, inputs, threshold, limits, job, restoring, added)


def _tune(
    plan: StudyPlan, start: StudyStart, clock: StudyClock, options: DriverOptions
) -> tuple[Any, Any]:
    """The tuning loop: ``(Tune's result grid, the stop it ended on)``."""
    tuner, concurrent = _make_tuner(plan, start, options)
    meter = _running_meter(tuner)
    spec = plan.spec
    print(
        f"study {spec.name!r}: up to {concurrent} trial(s) at once ({start.cpus:g} CPUs, "
        f"{spec.trial_cpus:g} per trial, batches of {spec.batch_size}, "
        f"max_concurrent {spec.max_concurrent})"
    )
    if start.restoring and plan.local:
        _name_damaged_checkpoints(plan)
    take_copy_seconds()  # only this run's copies
    clock.skip()
    return _fit(tuner, clock, concurrent, meter, start.cpus)


def _name_damaged_checkpoints(plan: StudyPlan) -> None:
    """One line per trial in flight (not recorded as ended) whose stored checkpoint does not
    load whole: the trial trains again (:func:`safe_bc.study.trial.resume_point`)."""
    ended = history_events(plan.out / HISTORY)[1]
    for folder in sorted(Path(plan.exp_path).glob("trial_*")):
        tid = folder.name.removeprefix("trial_")
        for checkpoint in [] if tid in ended else sorted(folder.glob("checkpoint_*")):
            problem = checkpoint_problem(checkpoint)
            if problem:
                print(
                    f"trial {tid}: its checkpoint is damaged ({problem[:300]}); the trial "
                    "trains again from its last whole checkpoint, else from its start"
                )


def _prepare_outputs(plan: StudyPlan, verbose: bool) -> None:
    """Tune's settings for this driver, the output folder checked writable (and emptied with
    ``fresh``, else the study's own records asked whether it may be resumed)."""
    os.environ.setdefault("TUNE_DISABLE_AUTO_CALLBACK_LOGGERS", "1")
    os.environ.setdefault("RAY_AIR_NEW_OUTPUT", "0")  # the terse status table of CLIReporter
    # SaveOnTrialEnd forces saves; Tune would call two within 5 s "excessive" and blame
    # CheckpointConfig(num_to_keep)
    os.environ.setdefault("TUNE_WARN_EXCESSIVE_EXPERIMENT_CHECKPOINT_SYNC_THRESHOLD_S", "0")
    check_persistence_api()
    install_atomic_upload()  # Tune's state on a local storage: whole files or the old ones
    take_failed_copy()  # a failed copy of an earlier study in this process is not this one's
    quiet_stop()  # a stopped study says so in one line
    quiet_full_disk()  # so does a full storage
    if not verbose:
        quiet_logs()
    out = plan.out
    check_result_write(out / "trials.parquet")  # a dirty tree fails now, not after the trials
    restorable = not plan.fresh and tune.Tuner.can_restore(plan.exp_path)
    published = not plan.fresh and not restorable and committed_unchanged(out)
    if published:  # the committed study on a clone: run it again, git keeps the committed one
        check_published(out, plan.settings)  # never another study over it
        print(
            f"{out}: the committed study, without its Tune experiment here: running it again "
            "from the start (compare the new tables with `git diff`)"
        )
    if plan.fresh or published:
        delete_storage_tree(plan.exp_path)
        kept = keep_earlier_run(out) if plan.fresh else None  # published: git keeps it
        if kept is not None:
            print(f"the earlier run's outputs: kept in {kept}/")
        for name in ("trials", "history", "final", "final_episodes", "final_paired"):
            (out / f"{name}.parquet").unlink(missing_ok=True)
        (out / FINISHED).unlink(missing_ok=True)  # first: a kill below leaves no claim
        for name in ("best.json", "pareto.png", "study.json", "optuna.db", HISTORY, TIMING,
                     TIMING_LOG, "timing.md"):  # fmt: skip
            (out / name).unlink(missing_ok=True)
        shutil.rmtree(out / STORE, ignore_errors=True)
        shutil.rmtree(out / BOARD, ignore_errors=True)
    else:  # the study's own records decide what may be resumed, before Ray starts
        check_resume(out, settings=plan.settings, exp_path=plan.exp_path,
                     restoring=restorable, local=plan.local)  # fmt: skip
        if restorable:
            check_optuna_copy(plan, plan.exp_path, finished=False)


EARLIER = "earlier"
"""The folder in ``results/<study>/`` where ``--fresh`` keeps the run it replaces."""
RUN_OUTPUTS = (
    "finished.json", "trials.parquet", "history.parquet", "final.parquet",
    "final_episodes.parquet", "final_paired.parquet", "certify.parquet",
    "certify_episodes.parquet", "best.json", "pareto.png", "study.json", "optuna.db",
    "history.jsonl", "timing.parquet", "timing.jsonl", "timing.md", "recommender", "tensorboard",
)  # fmt: skip
"""What one run of a study writes into ``results/<study>/`` (the first is its claim to have
finished: moved first, so that a kill leaves no claim)."""


def keep_earlier_run(out: Path) -> Path | None:
    """Move the outputs of the run in ``out`` (:data:`RUN_OUTPUTS`) into
    ``out/earlier/<UTC time of its newest output>/`` (``_2``, ... where taken), so that
    ``out`` is always the latest run and no run is lost; ``None``: nothing to keep."""
    present = [out / name for name in RUN_OUTPUTS if (out / name).exists()]
    if not present:
        return None
    newest = max(path.stat().st_mtime for path in present)
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime(newest))
    target, k = out / EARLIER / stamp, 1
    while target.exists():
        k += 1
        target = out / EARLIER / f"{stamp}_{k}"
    target.mkdir(parents=True)
    for path in present:
        os.replace(path, target / path.name)
    return target


def _study_demos(plan: StudyPlan, progress: bool) -> tuple[Any, dict[str, Any]]:
    """The study's demonstrations: the collection they come from checked against the study's
    env before anything is collected, the set collected when missing (another collection's
    set is refused), then read once for both the trials and the tables' record:
    ``(demonstrations, inputs record)``."""
    from safe_bc.distributed.collect import ensure_demos

    _check_env(plan.spec.env, plan.collect.env, plan.demos)
    if not (plan.demos / "dataset.json").exists():
        print(f"{plan.spec.demos}: no demonstrations yet; collecting the set the study expects")
    meta = ensure_demos(plan.demos, plan.collect, progress=progress).meta  # or refuses the set
    inputs: dict[str, Any] = {}
    if plan.validation is not None:
        if plan.validation_collect is not None:
            ensure_demos(plan.validation, plan.validation_collect, progress=progress)
        _check_validation_demos(plan.validation, plan.demos, meta)
        inputs["validation"] = {
            **dataset_record(plan.validation),
            "path": repo_relative(plan.validation),
        }
    demos, record = read_demonstrations(plan.demos)
    return demos, {"demos": record, **inputs}


def _make_tuner(
    plan: StudyPlan, start: StudyStart, options: DriverOptions
) -> tuple[tune.Tuner, int]:
    """The Tune run, restored from the experiment (with ``start.added`` more trials) or new,
    and how many trials run at once (a restored run keeps the limit it started with)."""
    spec, exp_path = plan.spec, plan.exp_path
    resources = tune.PlacementGroupFactory(list(plan.trial_resources))
    trainable = tune.with_resources(
        tune.with_parameters(options.trial_fn, job=start.job), resources
    )
    concurrent = spec.concurrency(start.cpus)  # how many at once, never which
    reporter = progress_reporter(spec) if options.verbose else None
    lines = [TrialLines(spec.trials)] if options.progress and not options.verbose else []
    verbose = 1 if options.progress and options.verbose else 0
    if start.restoring:
        more = f" with {start.added} more trial(s), {spec.trials} in all" if start.added else ""
        print(f"resuming study {spec.name!r} from {exp_path}{more}")
        try:
            tuner = tune.Tuner.restore(exp_path, trainable=trainable, resume_errored=True)
        except (pickle.UnpicklingError, EOFError) as e:  # Tune writes tuner.pkl in place
            raise ResumeRefused(
                f"{exp_path}/tuner.pkl: Tune's saved tuner is unreadable ({e}; a full disk "
                "when the study started leaves it so): restore it from a copy, or pass --fresh "
                "to start the study over"
            ) from None
        tuner._local_tuner._tune_config.num_samples = spec.trials
        for callback in tuner._local_tuner._run_config.callbacks or []:
            if isinstance(callback, TrialLines):  # "k/N" lines count to the new total
                callback.total = spec.trials
        _save_every_trial(tuner)
        restored = tuner._local_tuner._run_config  # this run's console, not the first run's
        kinds = {type(c) for c in restored.callbacks or []}  # trackers given on a resume
        added = [c for c in (trial_curves(plan), *options.callbacks) if type(c) not in kinds]
        restored.callbacks = [*(restored.callbacks or []), *added]
        restored.verbose, restored.progress_reporter = verbose, reporter
        # Tune restores the concurrency limit the study started with (its ConcurrencyLimiter's
        # saved state), whatever the cluster is now
        concurrent = tuner._local_tuner._tune_config.max_concurrent_trials or concurrent
        return tuner, concurrent
    searcher = make_searcher(spec, concurrent, export_to=plan.optuna_url)
    halving = make_scheduler(spec)
    tuner = tune.Tuner(
        trainable,
        tune_config=tune.TuneConfig(
            search_alg=searcher,
            scheduler=SaveOnTrialEnd(halving),
            num_samples=spec.trials,
            max_concurrent_trials=concurrent,
            reuse_actors=True,
            trial_dirname_creator=trial_dirname,
        ),
        run_config=tune.RunConfig(
            name=spec.name,
            storage_path=plan.storage,
            failure_config=tune.FailureConfig(max_failures=spec.max_failures),
            # a trial's (only) checkpoint forces a save of the experiment state too, so a
            # trial in flight when the driver dies resumes from it
            checkpoint_config=tune.CheckpointConfig(num_to_keep=1),
            callbacks=[
                JsonLoggerCallback(),
                CSVLoggerCallback(),
                TBXLoggerCallback(),  # every report of a trial, per round, in TensorBoard
                HistoryRecorder(str((plan.out / HISTORY).resolve())),
                RunningMeter(),
                trial_curves(plan),
                *lines,
                *options.callbacks,
            ],
            progress_reporter=reporter,
            verbose=verbose,
        ),
    )
    return tuner, concurrent


def trial_curves(plan: StudyPlan) -> TrialCurves:
    """The live writer of the trials' TensorBoard runs (:class:`TrialCurves`)."""
    stages = [stage.name for stage in plan.spec.stages()]
    return TrialCurves(str((plan.out / BOARD).resolve()), plan.spec.params, stages)


def _fit(
    tuner: tune.Tuner, clock: StudyClock, concurrent: int, meter: RunningMeter, cpus: float
) -> tuple[Any, Any]:
    """Tune's run, timed (also when it fails): ``(result grid, the stop it ended on)``."""

    def timed_tuning() -> None:
        clock.lap("tuning", slots=int(concurrent), running=meter.most, cpus=cpus)
        for seconds in take_copy_seconds():
            clock.add(COPY, seconds)

    try:
        grid = tuner.fit()
    except Exception as e:  # Tune wraps an OSError of a callback (a full disk) in a TuneError
        _fit_stopped()
        with contextlib.suppress(OSError):  # the time log must not hide the error
            timed_tuning()
        os_error = _os_error_in(e)
        if os_error is None:
            raise
        raise os_error from None
    timed_tuning()
    return grid, _fit_stopped()


def _final_and_certificate(
    plan: StudyPlan,
    start: StudyStart,
    grid: Any,
    report: TrialReport,
    clock: StudyClock,
    options: DriverOptions,
) -> tuple[FinalOutcome, Any, dict[str, Any]]:
    """The final phase on the report's candidates, its tables and plot, then the winner's
    certificate and recommender: ``(final outcome, certificate, meta with the final phase's
    seconds)``."""
    spec, candidates = plan.spec, report.candidates
    checkpoints = _checkpoints(grid, list(candidates["trial_id"]))
    clock.lap("final_checkpoints")
    t0 = time.perf_counter()
    store = FinalStore(plan.out / STORE)
    final = final_phase(
        spec, start.job, candidates, checkpoints, start.demos, progress=options.progress,
        store=store, on_curve=_final_curve_writer(plan, report.trials),
    )  # fmt: skip
    final_s = time.perf_counter() - t0
    parts = {f"final_{k}": v for k, v in final.seconds.items()}
    for phase, seconds in parts.items():
        clock.add(phase, seconds)
    clock.add("final_summary", max(final_s - sum(parts.values()), 0.0))
    clock.skip()
    meta = {**report.meta, "final_phase_seconds": round(time.perf_counter() - t0, 1)}
    _write_final(plan, final, candidates, meta)
    check_optuna_copy(plan, plan.exp_path)  # a missing copy is written again from the searcher
    mark_final_winner(plan.optuna_url, spec.name, final.winner, final.feasible)
    winner = final.winner if final.feasible else None
    write_study_board(plan, report.trials, report.history, winner, final.table)
    plot_pareto(
        report.trials,
        start.threshold,
        plan.out / "pareto.png",
        winner=final.winner if final.feasible else None,
        candidates=list(candidates["trial_id"]),
        title=f"{report.title}; final phase: "
        + (f"winner {final.winner}" if final.feasible else "no candidate feasible"),
        **plan.pareto_axes,
    )
    clock.lap("final_tables")
    certificate = deliver(plan, start.job, final, meta, store, progress=options.progress)
    clock.lap("certification")
    return final, certificate, meta


# --- the report ---------------------------------------------------------------------------------


def _report_trials(plan: StudyPlan, start: StudyStart, grid: Any) -> TrialReport:
    """``pareto.png`` (no verdict yet), then the trial and history tables, written; what they
    decide (the winner on the trials' own evaluation, the final phase's candidates)
    returned."""
    spec, out = plan.spec, plan.out
    trials, history, lost = _trial_rows(plan, grid)
    winner = choose_winner(trials, spec.objective)
    candidates = choose_candidates(trials, spec.final_candidates, spec.objective)
    errors = int((trials["status"] == "error").sum())
    finished = int(trials["status"].isin(["done", "stopped", "invalid", "error"]).sum())
    complete = finished >= spec.trials
    meta = trials_meta(
        plan, trials, threshold=start.threshold, limits=start.limits,
        expert_safety=start.demos.safety_mean, cost_limits=start.job.cost_limits,
        inputs=start.inputs, complete=complete, lost=lost, provenance=provenance(),
    )  # fmt: skip
    title = f"{spec.name}: {finished}/{spec.trials} trials"
    plot_pareto(trials, start.threshold, out / "pareto.png", title=title, **plan.pareto_axes)
    write_tables_atomic(out, {"trials": trials, "history": history}, meta)
    write_study_board(plan, trials, history, winner=None)
    return TrialReport(trials, meta, complete, errors, winner, candidates, title, history)


def write_study_board(
    plan: StudyPlan,
    trials: pd.DataFrame,
    history: pd.DataFrame,
    winner: str | None,
    final: pd.DataFrame | None = None,
) -> None:
    """Every trial's TensorBoard run with its HParams entry in ``results/<study>/tensorboard/``
    (:mod:`safe_bc.study.trial_curves`); a write that fails is named in one line, the
    study goes on (its tables are the record)."""
    spec = plan.spec
    try:
        write_board(
            plan.out, trials, history, params=spec.params, objective=spec.objective,
            stages=[stage.name for stage in spec.stages()],
            exp_path=plan.exp_path if plan.local else None, winner=winner, final=final,
        )  # fmt: skip
    except OSError as e:
        print(f"warning: the study's TensorBoard runs in {plan.out / BOARD} not written ({e})")


def _final_curve_writer(plan: StudyPlan, trials: pd.DataFrame) -> Any:
    """``on_curve`` of the final phase: each retrained agent's curve as a run of the board."""
    names = run_names(trials, plan.spec.params)

    def write(method: str, seed: int, curve: pd.DataFrame) -> None:
        try:
            write_final_curve(plan.out / BOARD, final_run_name(method, seed, names), curve)
        except OSError as e:
            print(f"warning: the final phase's curve of {method} (seed {seed}) not written ({e})")

    return write


def _trial_rows(plan: StudyPlan, grid: Any) -> tuple[pd.DataFrame, pd.DataFrame, list[str]]:
    """The trial table and the report history from Tune's results, the trials a killed driver
    lost named and their folders removed: ``(trials, history, lost trial ids)``."""
    params, out, exp_path = plan.spec.params, plan.out, plan.exp_path
    reports, records = read_history(out / HISTORY), _records(grid, params)
    # a trial whose end the study recorded keeps its folder, whatever Tune's state says
    ended = history_events(out / HISTORY)[1]
    trials = trial_table(records, params)
    history, lost = _study_history(reports, trials)
    if lost:
        print(
            f"{len(lost)} trial(s) were lost with a killed driver (the restored experiment does "
            f"not know them and ran others instead; their reports stay in {HISTORY} only): "
            + ", ".join(lost)
        )
    orphans = _remove_orphan_trial_dirs(exp_path, set(trials["trial_id"]) | ended)
    if orphans:
        print(f"removed the folders of {len(orphans)} such trial(s) from {exp_path}")
    return trials, history, lost


RECOMMENDER_DIR = "recommender"
"""The study's deliverable in ``results/<study>/`` (:mod:`safe_bc.study.recommender`)."""


def deliver(
    plan: StudyPlan,
    job: TrialJob,
    final: FinalOutcome,
    meta: dict[str, Any],
    store: FinalStore,
    *,
    progress: bool = True,
) -> dict[str, Any] | None:
    """Certify the final phase's winner on fresh tracks (with ``spec.certify_episodes``;
    ``certify*.parquet``) and write it as the study's recommender (``recommender/``: its
    weights per training seed, handover, ``d_s``, the demonstrations' identity, the
    certificate). Returns the certificate (``None`` without a certification)."""
    from safe_bc.study.certify import certify
    from safe_bc.study.final import final_workers, missed_constraints
    from safe_bc.study.recommender import RecommenderCard, write_recommender

    spec, out = plan.spec, plan.out
    winner = final.winner
    if winner is None:
        return None
    if not final.feasible:  # the closest candidate ships marked, never as the winner
        for line in missed_constraints(final.table):
            print(line)
        print(
            f"no candidate met every constraint: {out / RECOMMENDER_DIR}/ holds the closest "
            f"({winner}) marked uncertified; load_recommender refuses it unless "
            "allow_uncertified=True"
        )
    seeds = sorted(s for (m, s) in final.models if m == winner)
    certificate: dict[str, Any] = {}
    if spec.certify_episodes:
        agents = {s: final.agents[(winner, s)] for s in seeds}
        cert = certify(
            spec, job, agents, workers=final_workers(spec), store=store,
            identity=final.configs.get(winner), progress=progress,
        )  # fmt: skip
        cert_meta = {**meta, "certificate": cert.certificate, "winner": winner}
        tables = {"certify": cert.table, "certify_episodes": cert.episodes}
        write_tables_atomic(out, tables, cert_meta)
        certificate = cert.certificate
    nets = {s: shippable_net(final.agents.get((winner, s))) for s in seeds}
    if any(n is None for n in nets.values()):
        print(
            f"the winner's agents as evaluated are not plain BC nets (e.g. behind a stage's "
            f"shield): no {RECOMMENDER_DIR}/, since its weights would not be the certified agents'"
        )
        return certificate or None
    demos = meta["inputs"]["demos"]
    card = RecommenderCard(
        task=task_of(spec.env.env_id),
        env=json.loads(json.dumps(dataclasses.asdict(spec.env), default=str)),
        limits=dict(zip(job_dims(job), (float(x) for x in job.cost_limits), strict=True)),
        handover=None if spec.handover is None else spec.handover.to_dict(),
        expert=read_meta(Path(job.demos)).expert,
        demos={
            **{k: demos[k] for k in ("digest", "episodes", "collector")},
            "path": repo_relative(demos["path"]),
        },
        seeds=seeds,
        run_config=final.configs.get(winner, {}),
        source={
            "study": spec.name,
            "winner": winner,
            "feasible": bool(final.feasible),
            "command": meta.get("command", ""),
            "provenance": meta.get("provenance", {}),
        },
        certificate=certificate,
    )
    write_recommender(out / RECOMMENDER_DIR, card, nets)
    return certificate or None


def shippable_net(source: Any) -> tuple[BCNet, BCConfig] | None:
    """The net and config behind an evaluated agent's policy source, when the source is that
    net alone (a trained or retrained net; a stage's net without a shield): what a recommender
    ships, so that loading it gives the agent that was evaluated and certified. ``None`` for
    anything else (a shielded policy, a missing agent)."""
    from safe_bc.methods.common import unshielded
    from safe_bc.rollout.evaluate import NetSource

    source = unshielded(source)
    if isinstance(source, NetSource):
        return source.to_model()
    return None


def job_dims(job: TrialJob) -> tuple[str, ...]:
    """The safety dimensions of the study's task, in the order of its costs."""
    return task_defaults(task_of(job.spec.env.env_id)).safety_dims


FINISHED = "finished.json"
"""Written last by a study that ran to the end (the final tables written): a rerun of the same
study only reads the tables back and prints the result (:func:`finished_outcome`)."""


def finished_outcome(plan: StudyPlan) -> StudyOutcome | None:
    """The outcome of the plan's study when it ran to the end before with the same settings (its
    :data:`FINISHED` record matches and every output reads back whole), else ``None``.

    Raises:
        ValueError: one line naming the file, when one of the finished study's tables, its
            recommender (card or an agent's weights) or its Optuna copy (``optuna.db``) is
            damaged or not its own.
    """
    out = plan.out
    try:
        record = json.loads((out / FINISHED).read_text())
    except (OSError, json.JSONDecodeError):
        return None
    if record != plan.finished:
        return None  # other settings (e.g. --concurrent): the normal path resumes
    try:
        tables, best = _finished_tables(out), json.loads((out / "best.json").read_text())
        certificate = _finished_recommender(out)
    except (DatasetError, OSError, json.JSONDecodeError, ValueError) as e:
        raise ValueError(
            f"the finished study at {out} has a damaged output ({' '.join(str(e).split())}); "
            f"delete {out / FINISHED} and rerun the same command to rewrite the outputs (the "
            "trials and the final phase's finished work are kept and not redone)"
        ) from None
    trials, meta = tables["trials"]
    table, fmeta = tables["final"]
    check_optuna_copy(plan, str(meta.get("experiment_path", "")))
    final = FinalOutcome(
        table, tables["final_episodes"][0], best.get("trial_id"), bool(best.get("feasible")),
        str(best.get("message", "")), dict(fmeta.get("configs", {})),
        str(best.get("certified", "")), tables.get("final_paired", (pd.DataFrame(),))[0],
    )  # fmt: skip
    return StudyOutcome(
        True,
        trials,
        choose_winner(trials, plan.spec.objective),
        final,
        float(meta["threshold"]),
        out,
        str(meta.get("experiment_path", "")),
        int((trials["status"] == "error").sum()),
        timing=tables[TIMING_NAME][0] if TIMING_NAME in tables else None,
        certificate=certificate,
        unit=plan.spec.task().episodes_name,
    )


FINISHED_TABLES = ("trials", "history", "final", "final_episodes")
"""The tables every finished study has (each read whole before it says it finished)."""
TIMING_NAME = TIMING.removesuffix(".parquet")
"""The time table's name."""
OPTIONAL_TABLES = ("final_paired", TIMING_NAME, "certify", "certify_episodes")
"""The tables a finished study may lack (no paired comparison, a study finished before timings
were recorded, no certification); read whole where they exist."""


def _finished_tables(out: Path) -> dict[str, tuple[pd.DataFrame, dict[str, Any]]]:
    """Every table of the finished study at ``out``, read whole: ``{name: (rows, metadata)}``.

    Raises:
        DatasetError: a table that is missing (of :data:`FINISHED_TABLES`) or does not read
            whole, naming its file.
    """
    names = [*FINISHED_TABLES, *(n for n in OPTIONAL_TABLES if (out / f"{n}.parquet").exists())]
    return {name: read_table(out / f"{name}.parquet") for name in names}


def _finished_recommender(out: Path) -> dict[str, Any] | None:
    """The certificate of the finished study's recommender (``None``: no recommender, or one
    without a certificate), its card and every agent's weights checked against their SHA-256.

    Raises:
        RecommenderError: a damaged card or agent, naming the file.
    """
    if not (out / RECOMMENDER_DIR).exists():
        return None
    from safe_bc.study.recommender import load_recommender

    card = load_recommender(out / RECOMMENDER_DIR, allow_uncertified=True).card
    return card.certificate or None


def _checkpoints(grid: Any, trial_ids: Sequence[str]) -> dict[str, BCNet]:
    """Trial id -> its trained net, for the trials of ``trial_ids`` that have a checkpoint."""
    out = {}
    for r in grid:
        tid = str((r.metrics or {}).get("trial_id"))
        if tid not in trial_ids:
            continue
        try:
            if r.checkpoint is not None:
                with r.checkpoint.as_directory() as d:
                    out[tid] = load_checkpoint(d)[0]
                continue
        except (CheckpointError, OSError) as e:  # the final phase retrains it
            print(f"trial {tid}: its checkpoint is damaged ({' '.join(str(e).split())[:200]}); "
                  "the final phase trains it again")  # fmt: skip
            continue
        # resumed from a checkpoint Tune had not recorded (resume_point)
        stored = stored_checkpoint(r.filesystem, r.path)
        if stored is not None:
            out[tid] = stored[0]
    return out


def _write_final(
    plan: StudyPlan, final: FinalOutcome, candidates: pd.DataFrame, meta: dict[str, Any]
) -> None:
    spec, out = plan.spec, plan.out
    final_meta = {
        **meta,
        "final_design": {
            "candidates": list(candidates["trial_id"]),
            "train_seeds": sorted(int(s) for s in final.episodes["train_seed"].unique()),
            "tracks_per_seed": spec.final_tracks_per_seed(),
            "final_seed": spec.final_seed,
            "env_seeds": sorted(int(s) for s in final.episodes["env_seed"].unique()),
        },
        "winner": final.winner,
        "winner_feasible": final.feasible,
        "configs": final.configs,
    }
    tables = {"final": final.table, "final_episodes": final.episodes}
    if len(final.paired):
        tables["final_paired"] = final.paired
    write_tables_atomic(out, tables, final_meta)
    win = candidates[candidates["trial_id"] == final.winner]
    row = win.iloc[0].to_dict() if len(win) else {}
    best = {
        "study": spec.name,
        "chosen_on": "final re-evaluation: candidates retrained with "
        f"{spec.final_train_seeds} seeds on {final.episodes['env_seed'].nunique()} fresh "
        f"{spec.task().episodes_name}",
        "trial_id": final.winner,
        "feasible": final.feasible,
        "message": final.message,
        "certified": final.certified,
        "threshold": meta["threshold"],
        "dim_thresholds": meta["dim_thresholds"],
        "violation_tolerance": meta["violation_tolerance"],
        "cost_limits": meta["cost_limits"],
        "params": {k: row.get(k) for k in spec.params},
        "trial_metrics": {k: row.get(k) for k in trial_metrics()},
        "run_config": final.configs.get(final.winner or "", {}),
        "candidates": list(candidates["trial_id"]),
        "baseline": spec.baseline,
        "final": final.table.to_dict(orient="records"),
        "final_design": final_meta["final_design"],
        "command": meta["command"],
        "provenance": meta["provenance"],
    }
    write_json_atomic(out / "best.json", best, default=_json_default, allow_nan=True)


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
        f"(safety mean >= {outcome.threshold:.2f} and the violation constraint met), "
        f"{int((t['status'] == 'stopped').sum())} stopped by the screening, "
        f"{outcome.errors} failed",
        summary_lines(t, params),
    ]
    if outcome.stopped_by:
        name = signal.Signals(outcome.stopped_by).name
        what = "the trials" if not outcome.complete else "the final phase"
        lines.append(f"stopped by {name} before the end of {what}: run the same command again "
                     "to resume (finished trials are not run again)")  # fmt: skip
    elif not outcome.complete:
        lines.append("study incomplete: run the same command again to resume")
    elif outcome.winner is not None:
        lines.append(outcome.winner.message)
    else:
        import re

        # the trials' errors, most frequent first; messages that differ in numbers only count
        # as one
        reasons: dict[str, list[str]] = {}
        for error in t["error"]:
            if error:
                reasons.setdefault(re.sub(r"\d+(\.\d+)?(e[-+]?\d+)?", "#", error), []).append(error)
        lines.append(
            "no trial finished its evaluation; why:"
            if reasons
            else "no trial finished its evaluation (no trial recorded an error)"
        )
        for errors in sorted(reasons.values(), key=len, reverse=True):
            other = " (numbers differ between the trials)" if len(set(errors)) > 1 else ""
            lines.append(f"  {len(errors)} trial(s): {errors[0]}{other}")
    if outcome.final is not None and len(outcome.final.table):
        cols = ["method", "n_train_seeds", "n_episodes", "reward", "reward_lo", "reward_hi",
                "safety_mean", "violation_steps", "episodes_with_violation", "deferred_share",
                "feasible"]  # fmt: skip
        tab = outcome.final.table
        unit = outcome.unit
        lines.append(
            f"final phase on fresh held-out {unit} (95% bootstrap CIs over seeds, {unit}):"
        )
        lines.append(
            tab[[c for c in cols if c in tab]].to_string(
                index=False, float_format=lambda x: f"{x:.2f}"
            )
        )
        lines.append(outcome.final.message)
        feasible = outcome.final.feasible
        if not feasible:
            from safe_bc.study.final import missed_constraints

            lines += missed_constraints(tab)
        who = "the winner" if feasible else "the closest candidate (uncertified)"
        if outcome.final.certified:
            lines.append(f"{who}, on the fresh {unit}: {outcome.final.certified}")
        paired = outcome.final.paired
        if outcome.final.winner is not None and len(paired):
            for _, r in paired[paired["method"] == outcome.final.winner].iterrows():
                lines.append(
                    f"{'winner' if feasible else 'closest'} - {r['vs']} (paired, same {unit}): "
                    f"reward {r['d_reward']:+.1f} "
                    f"[{r['d_reward_lo']:+.1f}, {r['d_reward_hi']:+.1f}]"
                )
    if outcome.certificate:
        from safe_bc.study.certify import certificate_line

        certified = outcome.final is None or outcome.final.feasible
        lines.append(
            ("the recommender, " if certified else "the uncertified recommender, ")
            + certificate_line(outcome.certificate)
        )
        how = "safe_bc.load_recommender" + ("" if certified else ", allow_uncertified=True")
        lines.append(f"recommender: {outcome.out / RECOMMENDER_DIR}/ ({how})")
    if outcome.timing is not None and len(outcome.timing):
        lines += timing_lines(outcome.timing)
        lines.append(f"where the time went: {outcome.out / 'timing.md'}")
    lines.append(f"outputs in {outcome.out}/")
    return "\n".join(lines)
