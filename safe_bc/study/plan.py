"""The plan of one run of a study: what the driver does, decided from its ``StudySpec`` once.

Pure (no Ray, no file is read or written; local paths are made absolute against the working
folder): :func:`plan_study` turns the spec and the command's switches into a
:class:`StudyPlan` (where the outputs, the Tune experiment and the Optuna copy live, what a
resume compares, which phases run); :func:`constraint_bars`, :func:`run_identity` and
:func:`trials_meta` finish the plan's records once the demonstrations are known. The driver
(:mod:`safe_bc.study.run`) runs the plan and reports on it.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import pandas as pd

from safe_bc.data.provenance import repo_relative
from safe_bc.rollout.collect import CollectConfig
from safe_bc.seeds import VALIDATION_SEED
from safe_bc.study.spec import ConstraintBars, StudySpec, settings_of
from safe_bc.tasks import TaskSpec, task_defaults, task_of


def is_uri(path: str) -> bool:
    """Whether ``path`` is a storage URI (``s3://...``) rather than a local folder."""
    return "://" in path


def experiment_location(spec: StudySpec) -> tuple[str, str]:
    """``(storage_path, experiment_path)``: local folders made absolute, URIs kept."""
    storage = spec.storage if is_uri(spec.storage) else str(Path(spec.storage).resolve())
    return storage, f"{storage.rstrip('/')}/{spec.name}"


def default_optuna_storage(spec: StudySpec) -> str:
    """The study's Optuna storage URL: ``spec.optuna_storage``, else a SQLite file beside the
    tables, ``sqlite:///<results>/<name>/optuna.db`` (absolute path)."""
    if spec.optuna_storage:
        return spec.optuna_storage
    return f"sqlite:///{(spec.results / spec.name / 'optuna.db').resolve()}"


def safety_axis_label(env_id: str) -> str:
    """The safety mean's axis label in the task's words (``px to the grass`` for the car;
    the cost's units where a task names none)."""
    return _safety_label(task_defaults(task_of(env_id)))


def _safety_label(task: TaskSpec) -> str:
    units = list(dict.fromkeys(task.safety_units)) or ["cost units"]
    if task.drawing is not None:
        what = task.drawing.closest
    elif len(units) == 1:
        what = f"distance to the limit, {units[0]}"
    else:
        what = f"each step's smallest margin: {', '.join(units)}"
    return f"safety mean ({what}; higher is safer)"


@dataclass(frozen=True)
class StudyPlan:
    """One run of a study, decided before anything runs (:func:`plan_study`)."""

    spec: StudySpec
    """The study; the trials and the final phase read their own settings from it."""
    out: Path
    """``results/<study>/``: the tables, plots and records."""
    storage: str
    """Tune's storage: a local folder made absolute, or a URI."""
    exp_path: str
    """The Tune experiment, ``<storage>/<study>``."""
    local: bool
    """The experiment is a local folder (its state can be read, its trial count raised)."""
    optuna_url: str
    """The Optuna copy's storage URL."""
    fresh: bool
    """Discard a previous run of the study (Tune experiment and outputs) first."""
    command: str
    """The command line, recorded in every table's metadata."""
    final: bool
    """Run the final phase, the certification and the finished mark after the trials."""
    demos: Path
    """The demonstrations, absolute."""
    collect: CollectConfig
    """The collection the demonstrations must come from (collected when missing)."""
    validation: Path | None
    """The demonstration set of the curves' validation loss, absolute, or ``None``."""
    validation_collect: CollectConfig | None
    """The collection :attr:`validation` must come from when the study collects it
    (``StudySpec.validation_episodes``; collected when missing); ``None``: a set the spec
    names (``validation_demos``), or none."""
    summary: dict[str, Any]
    """``StudySpec.summary()``: stored with every table."""
    settings: dict[str, Any]
    """What shapes the trials and the final phase (:func:`safe_bc.study.spec.settings_of`): a resume
    compares it."""
    finished: dict[str, Any]
    """The finished mark's record: a rerun with the same one only reads the tables back."""
    trial_resources: tuple[dict[str, float], ...]
    """One trial's placement group: its own process, then each rollout worker."""
    pareto_axes: dict[str, str]
    """``pareto.png``'s axes: the objective against the safety mean in the task's words."""


def plan_study(spec: StudySpec, *, fresh: bool, command: str, final: bool) -> StudyPlan:
    """The plan of a run of ``spec`` (``fresh``, ``command``, ``final``: :class:`StudyPlan`)."""
    storage, exp_path = experiment_location(spec)
    optuna_url = default_optuna_storage(spec)
    task = task_defaults(task_of(spec.env.env_id))
    axes = {"objective": spec.objective, "safety_label": _safety_label(task)}
    summary = spec.summary()
    settings = settings_of(summary)
    collect = spec.collect or CollectConfig.for_task(task)
    validation, validation_collect = validation_set(spec, collect)
    return StudyPlan(
        spec=spec,
        out=spec.results / spec.name,
        storage=storage,
        exp_path=exp_path,
        local=not is_uri(exp_path),
        optuna_url=optuna_url,
        fresh=fresh,
        command=command,
        final=final,
        demos=spec.demos.resolve(),
        collect=collect,
        validation=validation,
        validation_collect=validation_collect,
        summary=summary,
        settings=settings,
        finished=json.loads(json.dumps({"study": summary}, sort_keys=True, default=str)),
        trial_resources=(
            {"CPU": spec.cpus_per_trial},
            *[{"CPU": spec.cpus_per_worker}] * spec.rollout_workers,
        ),
        pareto_axes=axes,
    )


def validation_path(demos: Path) -> Path:
    """Where a study keeps the validation set it collects beside ``demos``.

    >>> validation_path(Path("data/demos")).as_posix()
    'data/demos_validation'
    """
    return demos.with_name(f"{demos.name}_validation")


def validation_set(
    spec: StudySpec, collect: CollectConfig
) -> tuple[Path | None, CollectConfig | None]:
    """The study's validation set, absolute, and the collection it comes from when the study
    collects it (``collect`` with :attr:`StudySpec.validation_episodes` episodes on the
    tracks of :data:`safe_bc.seeds.VALIDATION_SEED`): ``(None, None)`` without one."""
    if spec.validation_demos is not None:
        return spec.validation_demos.resolve(), None
    if not spec.validation_episodes:
        return None, None
    episodes = int(spec.validation_episodes)
    made = replace(collect, episodes=episodes, seed=VALIDATION_SEED)
    return validation_path(spec.demos).resolve(), made


def constraint_bars(
    spec: StudySpec, expert_safety: float, dim_safety: Mapping[str, float]
) -> tuple[float, ConstraintBars]:
    """The study's safety threshold (the expert's demonstrated safety mean unless the spec
    sets one) and the bars every trial is held to."""
    threshold = expert_safety if spec.threshold is None else float(spec.threshold)
    limits = ConstraintBars(
        threshold,
        dim_safety,
        spec.violation_tolerance,
        spec.safety_constraint,
        spec.violation_bound,
        spec.violation_share_limit,
        spec.deferred_share_limit if spec.handover is not None else 1.0,
    )
    return threshold, limits


def run_identity(
    plan: StudyPlan, threshold: float, cost_limits: Sequence[float], inputs: dict[str, Any]
) -> dict[str, Any]:
    """What a resumed study must share with the run it resumes (``study.json``)."""
    return {
        "trials": plan.spec.trials,
        "threshold": threshold,
        "limits": list(cost_limits),
        "batch_size": plan.spec.batch_size,
        "demos_digest": inputs["demos"]["digest"],
        **({"validation_digest": inputs["validation"]["digest"]} if "validation" in inputs else {}),
        "experiment_path": repo_relative(plan.exp_path),  # inside the repository: relative
        "settings": plan.settings,
    }


def trials_meta(
    plan: StudyPlan,
    trials: pd.DataFrame,
    *,
    threshold: float,
    limits: ConstraintBars,
    expert_safety: float,
    cost_limits: Sequence[float],
    inputs: dict[str, Any],
    complete: bool,
    lost: list[str],
    provenance: dict[str, Any],
) -> dict[str, Any]:
    """The metadata of the trial and history tables (and, extended, of every later table)."""
    spec = plan.spec
    first = trials["eval_seeds"].iloc[0] if len(trials) else None
    return {
        "command": plan.command,
        "study": plan.summary,
        "threshold": threshold,
        "dim_thresholds": dict(limits.dim_thresholds),
        "violation_tolerance": spec.violation_tolerance,
        "violation_bound": spec.violation_bound,
        "violation_share_limit": spec.violation_share_limit,
        "objective": spec.objective,
        "safety_constraint": spec.safety_constraint,
        "expert_demo_safety_mean": expert_safety,
        "cost_limits": list(cost_limits),
        "inputs": inputs,
        "handover": None if spec.handover is None else spec.handover.to_dict(),
        "deferred_share_limit": spec.deferred_share_limit if spec.handover is not None else None,
        "seeds": {
            "train_seed": spec.base.bc.train.seed,
            "eval_seed": spec.eval_seed,
            "eval_seeds": [int(x) for x in str(first).split(",")] if first else [],
            "final_seed": spec.final_seed,
            "certify_seed": spec.certify_seed if spec.certify_episodes else None,
            "sampler_seed": spec.sampler_seed,
        },
        "experiment_path": plan.exp_path,
        "complete": complete,
        "lost_trials": lost,
        "provenance": provenance,
    }
