"""The study's searcher and scheduler: Optuna's constrained TPE inside Ray Tune, and ASHA.

* :class:`ConstrainedOptunaSearch` hands each finished trial's constraints (``<= 0``
  feasible) to Optuna with ``Trial.set_constraint`` before the usual ``tell``: Ray's
  ``OptunaSearch`` alone drops a ``TPESampler(constraints_func=...)`` silently. It reads
  Ray-private attributes of ``OptunaSearch`` (``_ot_trials``, ``_completed_trials``,
  ``_ot_study``); :func:`check_private_api` names them and the tests run it against the
  pinned Ray, so an upgrade that moves them fails loudly.
* :func:`make_scheduler` is successive halving (``AsyncHyperBandScheduler``) on the trials'
  cheap first evaluation (``screen_episodes`` tracks).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from optuna.samplers import TPESampler
from ray.tune.schedulers import AsyncHyperBandScheduler, FIFOScheduler, TrialScheduler
from ray.tune.search.optuna import OptunaSearch

from safe_bc.study import CONSTRAINTS, OBJECTIVE, Choice, Float, Int, Param, StudySpec

SCORE = "score"
"""Result key of the screening score ASHA compares: the reward, minus :data:`SCREEN_PENALTY`
when a constraint is broken on the screened tracks."""
ROUND = "eval_round"
"""Result key counting a trial's evaluation rounds (1: screened, 2: fully evaluated)."""
SCREEN_PENALTY = 1e6
"""Subtracted from the screened reward of a trial that breaks a constraint (so feasible
trials always rank above infeasible ones, and infeasible ones by reward)."""

PRIVATE_API = ("_ot_trials", "_completed_trials", "_ot_study")
"""``OptunaSearch`` attributes this module relies on (Ray 2.60)."""


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
    """``OptunaSearch`` that passes ``result[key]`` for every ``name -> key`` of
    ``constraints`` to Optuna as the trial's constraint ``name``.

    Optuna 5's TPE reads constraints that ``Trial.set_constraint(name, value)`` stored on the
    trial (all ``<= 0``: feasible), so they are set in ``on_trial_complete`` before ``tell``.
    Results whose objective is not a finite number (the post-training report) are not
    forwarded as intermediate values; a trial without finite constraints (an invalid
    configuration) is told as failed.
    """

    def __init__(
        self, *args: Any, constraints: Mapping[str, str] = CONSTRAINTS, **kwargs: Any
    ) -> None:
        self._constraint_keys = dict(constraints)
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
            values = {name: result.get(key) for name, key in self._constraint_keys.items()}
            if all(isinstance(v, int | float) and math.isfinite(v) for v in values.values()):
                for name, value in values.items():
                    if name not in ot_trial.constraints:
                        ot_trial.set_constraint(name, float(value))
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


def check_private_api(searcher: OptunaSearch) -> None:
    """Raise ``RuntimeError`` naming the Ray-private attributes a searcher lacks.

    Call it on a searcher that has been set up (after ``set_search_properties`` or a trial).
    """
    missing = [a for a in PRIVATE_API if not hasattr(searcher, a)]
    if missing:
        raise RuntimeError(
            f"ray.tune.search.optuna.OptunaSearch no longer has {', '.join(missing)}; "
            "safe_bc's constrained searcher needs updating for this Ray version"
        )


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


def make_scheduler(spec: StudySpec) -> TrialScheduler:
    """Successive halving on the screening round when the study screens, else FIFO.

    Rung 1 is the screened score: a trial is stopped when its score is below the median of
    the scores recorded at that rung so far (reduction factor 2); round 2 is the end.
    """
    if not spec.screens:
        return FIFOScheduler()
    return AsyncHyperBandScheduler(
        time_attr=ROUND,
        metric=SCORE,
        mode="max",
        max_t=2,
        grace_period=1,
        reduction_factor=2,
    )


def screen_score(reward: float, constraint: float) -> float:
    """The screening score: ``reward`` when the constraint is met, else ``reward - 1e6``.

    >>> screen_score(800.0, -0.5), screen_score(900.0, 0.1)
    (800.0, -999100.0)
    """
    ok = math.isfinite(constraint) and constraint <= 0
    return float(reward) if ok else float(reward) - SCREEN_PENALTY
