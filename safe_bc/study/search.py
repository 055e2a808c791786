"""The study's searcher and scheduler: Optuna's constrained TPE inside Ray Tune, in batches,
and successive halving.

* :class:`ConstrainedOptunaSearch` hands each finished trial's constraints (``<= 0``
  feasible) to Optuna with ``Trial.set_constraint`` before the usual ``tell``: Ray's
  ``OptunaSearch`` alone drops a ``TPESampler(constraints_func=...)`` silently. It reads
  Ray-private attributes of ``OptunaSearch`` (``_ot_trials``, ``_completed_trials``,
  ``_ot_study``); :func:`check_private_api` names them and the tests run it against the
  pinned Ray, so an upgrade that moves them fails loudly.
* With ``batch_size`` (``StudySpec.batch_size``) the searcher is deterministic whatever the
  concurrency: suggestions come in batches of that size, every suggestion of a batch is made
  before any result of it is told, and a batch's results are told to Optuna in trial order
  once all of them are in (a trial of the next batch is suggested only then). The trial's
  number (its suggestion order, the Optuna trial number) travels in its config as
  :data:`NUMBER`.
* :func:`make_scheduler` is successive halving on the trials' cheap first evaluation
  (``screen_episodes`` tracks): :class:`BatchHalving` (deterministic, with batches), else
  Tune's ``AsyncHyperBandScheduler``.
"""

from __future__ import annotations

import contextlib
import copy
import json
import math
import time
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from optuna.samplers import TPESampler
from ray.tune.schedulers import AsyncHyperBandScheduler, FIFOScheduler, TrialScheduler
from ray.tune.search.optuna import OptunaSearch

from safe_bc.study.plan import StudyPlan, is_uri
from safe_bc.study.spec import CONSTRAINTS, Choice, Float, Int, Param, StudySpec

SCORE = "score"
"""Result key of the screening score the halving compares: the reward, minus :data:`SCREEN_PENALTY`
when a constraint is broken on the screened tracks."""
ROUND = "eval_round"
"""Result key counting a trial's evaluation rounds (1: screened, 2: fully evaluated)."""
SCREEN_PENALTY = 1e6
"""Subtracted from the screened reward of a trial that breaks a constraint (so feasible
trials always rank above infeasible ones, and infeasible ones by reward)."""

SCREENED = "screen_score_r1"
"""Result key keeping a trial's screening score in its later reports (:class:`BatchHalving`
reads it from every earlier trial's last result)."""
STOPPED = "stopped_by_screening"
"""Trial user attribute the searcher sets on a trial stopped by the screening (its last
result is of the ``screened`` phase): the Optuna copy stores such a trial PRUNED."""
WINNER = "final_winner"
"""Study and trial user attribute of the Optuna copy naming the final phase's winner
(:func:`mark_final_winner`): the study's holds the Tune trial id (``None``: no winner), the
winning trial's is ``True``."""

NUMBER = "trial_number"
"""Config key of a trial's number: its suggestion order (0, 1, ...), the Optuna trial number
(set by a batched :class:`ConstrainedOptunaSearch`)."""

PRIVATE_API = ("_ot_trials", "_completed_trials", "_ot_study")
"""``OptunaSearch`` attributes this module relies on (Ray 2.60)."""

_COPY_SECONDS: list[float] = []
"""Wall-clock of each copy of the Optuna study made in this process since the last
:func:`take_copy_seconds` (the searcher runs in the driver)."""


def take_copy_seconds() -> list[float]:
    """The seconds of every Optuna copy (:meth:`ConstrainedOptunaSearch.export`) made in this
    process since the last call, in order, and forget them."""
    out = list(_COPY_SECONDS)
    _COPY_SECONDS.clear()
    return out


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

    With ``batch_size``, suggestions are made in batches (see the module docstring): the
    same study file gives the same suggestions whatever the number of trials running at once.
    ``None``: every result is told as it arrives (the order in which concurrent trials finish
    then changes later suggestions).
    """

    def __init__(
        self,
        *args: Any,
        constraints: Mapping[str, str] = CONSTRAINTS,
        batch_size: int | None = None,
        max_trials: int | None = None,
        export_to: str | None = None,
        **kwargs: Any,
    ) -> None:
        self._constraint_keys = dict(constraints)
        if batch_size is not None and batch_size < 1:
            raise ValueError(f"batch_size must be >= 1 or None, got {batch_size}")
        self._batch_size = batch_size
        self._max_trials = max_trials
        """The study's trial count: the last batch is complete with the last trial."""
        self._numbers: dict[str, int] = {}
        """Tune trial id -> its number (suggestion order)."""
        self._batch: list[str] = []
        """Trial ids of the current batch, in suggestion order."""
        self._held: dict[str, tuple[dict | None, bool]] = {}
        """Results of the current batch's finished trials, not yet told."""
        self._export_to = export_to
        """Optuna storage URL the study is copied to after every tell (``None``: none)."""
        super().__init__(*args, **kwargs)

    def suggest(self, trial_id: str) -> dict | None:
        size = self.__dict__.get("_batch_size")
        if size is None:  # unbatched (also a searcher pickled before batches existed)
            config = super().suggest(trial_id)
            self._ot_trials[trial_id].set_user_attr("tune_trial_id", trial_id)
            return config
        if trial_id not in self._numbers:
            if len(self._batch) >= size:
                return None  # wait until the whole batch is in and told
            self._numbers[trial_id] = len(self._numbers)
            self._batch.append(trial_id)
        config = super().suggest(trial_id)
        self._ot_trials[trial_id].set_user_attr("tune_trial_id", trial_id)
        return {**config, NUMBER: self._numbers[trial_id]}

    def on_trial_result(self, trial_id: str, result: dict) -> None:
        value = result.get(self.metric) if isinstance(self.metric, str) else None
        if isinstance(value, int | float) and math.isfinite(value):
            super().on_trial_result(trial_id, result)

    def on_trial_complete(
        self, trial_id: str, result: dict | None = None, error: bool = False
    ) -> None:
        if self.__dict__.get("_batch_size") is None or trial_id not in self._batch:
            self._tell(trial_id, result, error)
            self.export()
            return
        self._held[trial_id] = (result, error)
        first = self._numbers[self._batch[0]]
        total = self.__dict__.get("_max_trials")
        size = self._batch_size if total is None else min(self._batch_size, total - first)
        if len(self._batch) >= size and len(self._held) == len(self._batch):
            for tid in self._batch:  # the batch is in: tell it in trial order
                if tid not in self._completed_trials:
                    self._tell(tid, *self._held[tid])
            self._batch, self._held = [], {}
            self.export()

    def export(self) -> None:
        """Copy the Optuna study (every trial with its parameters, value, state, constraints
        and Tune trial id) to the ``export_to`` storage, replacing an earlier copy."""
        url = self.__dict__.get("_export_to")
        if url and self._ot_study is not None:
            start = time.perf_counter()
            attrs = {"objective": self._metric, "constraints": dict(self._constraint_keys),
                     "batch_size": self.__dict__.get("_batch_size")}  # fmt: skip
            try:
                export_study(self._ot_study, url, attrs, metric=self._metric,
                             constraint_names=list(self._constraint_keys))  # fmt: skip
            except Exception as e:  # a copy for other tools must never stop the study
                warnings.warn(
                    f"could not copy the Optuna study to {url}: {one_line(e)}", stacklevel=2
                )
            _COPY_SECONDS.append(time.perf_counter() - start)

    def batch_pending(self) -> list[str]:
        """Trial ids of the current batch whose results are not in yet."""
        return [t for t in self.__dict__.get("_batch", []) if t not in self._held]

    def _tell(self, trial_id: str, result: dict | None, error: bool) -> None:
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
            if not error and result.get("phase") == "screened":
                ot_trial.set_user_attr(STOPPED, True)  # read by the copy only, not by TPE
        super().on_trial_complete(trial_id, result, error)

    @property
    def study(self) -> Any:
        """The Optuna study (its trials carry ``.constraints``)."""
        return self._ot_study

    def constraints_by_trial(self) -> dict[str, dict[str, float]]:
        """Tune trial id -> the constraint values Optuna holds for that trial."""
        return {tid: dict(t.constraints) for tid, t in self._ot_trials.items()}


def one_line(error: BaseException) -> str:
    """The first line of ``error``'s message (SQLAlchemy's errors add the SQL statement, its
    parameters and a link on further lines)."""
    lines = str(error).strip().splitlines()
    return lines[0] if lines else type(error).__name__


def export_study(
    study: Any,
    url: str,
    attrs: Mapping[str, Any] | None = None,
    *,
    metric: str | None = None,
    constraint_names: Sequence[str] = (),
    winner: str | None = None,
) -> None:
    """Write ``study`` (any Optuna study, e.g. the searcher's in-memory one) to the Optuna
    storage at ``url`` under the same name, replacing a study of that name there; ``attrs``
    are added to the copy's study user attributes.

    The copy is made for other tools: ``metric`` names its objective
    (``Study.set_metric_names``), and every trial's named constraints are also written as the
    list optuna-dashboard reads (:func:`with_constraint_list`). A trial the screening stopped
    is stored PRUNED (:func:`as_pruned`), and the trial whose Tune trial id is ``winner`` is
    marked (:func:`with_winner_mark`).

    A SQLite file is written to a temporary file and renamed over the old one (a reader or a
    killed driver never sees half a study); other RDB URLs (PostgreSQL, MySQL) are updated
    in place (the old study deleted, then the copy added).
    """
    import os

    import optuna

    prefix = "sqlite:///"
    if url.startswith(prefix):
        path = Path(url.removeprefix(prefix))
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        tmp.unlink(missing_ok=True)
        try:
            storage = optuna.storages.RDBStorage(f"{prefix}{tmp}")
            _copy_into(study, storage, attrs, metric, constraint_names, winner)
            storage.remove_session()
            storage.engine.dispose()
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)
        return
    storage = optuna.storages.RDBStorage(url)
    with contextlib.suppress(KeyError):  # no earlier copy
        optuna.delete_study(study_name=study.study_name, storage=storage)
    _copy_into(study, storage, attrs, metric, constraint_names, winner)


def with_constraint_list(trial: Any, names: Sequence[str] = ()) -> Any:
    """``trial`` (a ``FrozenTrial``) with its named constraints (``Trial.set_constraint``) also
    stored as the list form, the system attribute ``constraints`` (``<= 0`` feasible): the
    form ``TPESampler(constraints_func=...)`` writes and optuna-dashboard 0.21 reads (it shows
    no constraint of a trial without it). Values follow ``names``, then any other names in
    sorted order. Optuna reads both forms, so the copy's ``.constraints`` holds each value twice:
    by name and under its list index (``"0"``, ``"1"``); feasibility is the same.
    A trial without named constraints, or with a list already, is returned as it is.
    """
    named = trial.constraints
    if not named or "constraints" in trial.system_attrs:
        return trial
    order = [n for n in names if n in named] + sorted(set(named) - set(names))
    out = copy.copy(trial)
    out.system_attrs = {**trial.system_attrs, "constraints": [float(named[n]) for n in order]}
    return out


def as_pruned(trial: Any) -> Any:
    """``trial`` (a ``FrozenTrial``) stored PRUNED when the screening stopped it (user
    attribute :data:`STOPPED`) and it was told COMPLETE (the searcher tells every stopped
    trial COMPLETE with its last value, as Ray's ``OptunaSearch`` does). Its value stays: the
    objective of its last report, which is its last intermediate value, the value Optuna's
    own ``tell(state=PRUNED)`` keeps. Any other trial is returned as it is."""
    from optuna.trial import TrialState

    if not trial.user_attrs.get(STOPPED) or trial.state != TrialState.COMPLETE:
        return trial
    out = copy.copy(trial)
    out.state = TrialState.PRUNED
    return out


def with_winner_mark(trial: Any, winner: str | None) -> Any:
    """``trial`` with the user attribute :data:`WINNER` ``True`` when its Tune trial id is
    ``winner``, and without it otherwise (an earlier mark is taken off); a trial that needs no
    change is returned as it is."""
    mark = winner is not None and trial.user_attrs.get("tune_trial_id") == winner
    if mark == bool(trial.user_attrs.get(WINNER)):
        return trial
    out = copy.copy(trial)
    out.user_attrs = {k: v for k, v in trial.user_attrs.items() if k != WINNER}
    if mark:
        out.user_attrs[WINNER] = True
    return out


def mark_final_winner(url: str, study_name: str, winner: str | None, feasible: bool) -> None:
    """Mark the final phase's winner (Tune trial id ``winner``, ``best.json``'s ``trial_id``)
    in the study's Optuna copy at ``url``: study user attributes :data:`WINNER` (the trial id),
    ``final_winner_number`` (its Optuna trial number) and ``final_winner_feasible``, and the
    winning trial's user attribute :data:`WINNER` ``True``. The copy is rewritten as
    :func:`export_study` writes it. A copy that cannot be read or written is left as it is
    with a warning (it is for other tools; the study's own result is ``best.json``)."""
    import optuna

    try:
        stored = optuna.load_study(study_name=study_name, storage=url)
        # held in memory: an RDB copy is deleted before it is written again
        study = optuna.create_study(study_name=study_name, directions=stored.directions)
        study.add_trials(stored.trials)
        for key, value in stored.user_attrs.items():
            study.set_user_attr(key, value)
        ids = {t.user_attrs.get("tune_trial_id"): t.number for t in study.trials}
        if winner is not None and winner not in ids:
            raise ValueError(f"it has no trial with Tune trial id {winner!r}")
        attrs = {WINNER: winner, "final_winner_number": ids.get(winner),
                 "final_winner_feasible": bool(feasible)}  # fmt: skip
        metric = stored.metric_names[0] if stored.metric_names else None
        export_study(study, url, attrs, metric=metric, winner=winner)
    except Exception as e:  # a copy for other tools must never stop the study
        warnings.warn(f"could not mark the final winner in {url}: {one_line(e)}", stacklevel=2)


def _copy_into(
    study: Any,
    storage: Any,
    attrs: Mapping[str, Any] | None,
    metric: str | None = None,
    constraint_names: Sequence[str] = (),
    winner: str | None = None,
) -> None:
    import optuna

    target = optuna.create_study(
        storage=storage, study_name=study.study_name, directions=study.directions
    )
    if metric is not None and len(study.directions) == 1:
        with warnings.catch_warnings():  # experimental since Optuna 3.2, still in 5.0
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            target.set_metric_names([metric])
    for key, value in {**study.user_attrs, **(attrs or {})}.items():
        target.set_user_attr(key, value)
    trials = study.get_trials(deepcopy=False)
    copied = [as_pruned(with_constraint_list(t, constraint_names)) for t in trials]
    target.add_trials([with_winner_mark(t, winner) for t in copied])


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


def make_searcher(
    spec: StudySpec, concurrent: int | None = None, *, export_to: str | None = None
) -> ConstrainedOptunaSearch:
    """The study's constrained TPE searcher (maximises ``spec.objective``, copying its Optuna
    study to ``export_to``, a storage URL, when given), batched when the
    study says so (``spec.batch_size``). With batches, the constant liar follows the batch
    size, never the trials at once (``concurrent``, resolved from the cluster, or
    ``max_concurrent``, which ``--max-concurrent`` changes); without batches (whose trials
    depend on the concurrency anyway) it is on when more than one trial may run at once."""
    if spec.batch_size is not None:
        parallel = spec.batch_size
    else:
        parallel = concurrent or spec.max_concurrent or 2
    sampler = TPESampler(
        seed=spec.sampler_seed,
        n_startup_trials=spec.startup_trials,
        multivariate=True,
        constant_liar=parallel > 1,
    )
    return ConstrainedOptunaSearch(
        space=SpaceSampler(spec.space),
        metric=spec.objective,
        mode="max",
        sampler=sampler,
        study_name=spec.name,
        batch_size=spec.batch_size,
        max_trials=spec.trials,
        export_to=export_to,
    )


def raise_trial_count(experiment_path: str | Path, trials: int) -> None:
    """Let a (local) Tune experiment that ran fewer trials run up to ``trials`` when it is
    restored: its search generator's sample count (and its "finished" flag, set when the last
    sample was drawn) and the searcher's trial count (which closes the last batch) are
    raised in their newest saved states, written back atomically. The sampler keeps every
    trial it was told, so the new trials continue the same Optuna study."""
    import ray.cloudpickle as cloudpickle

    from safe_bc.data.atomic import write_bytes_atomic

    def newest(pattern: str) -> Path:
        found = sorted(Path(experiment_path).glob(pattern))  # Tune's names sort by time
        if not found:
            raise ValueError(f"{experiment_path}: no saved {pattern} to add trials to")
        return found[-1]

    gen = newest("search_gen_state-*.json")  # a cloudpickle, whatever Tune's name says
    state = cloudpickle.loads(gen.read_bytes())
    if trials < state["counter"]:
        raise ValueError(f"{experiment_path} has {state['counter']} trials, more than {trials}")
    state["total_samples"], state["finished"] = trials, False
    write_bytes_atomic(gen, cloudpickle.dumps(state))
    path = newest("searcher-state-*.pkl")
    searcher = cloudpickle.loads(path.read_bytes())
    searcher["_max_trials"] = trials
    write_bytes_atomic(path, cloudpickle.dumps(searcher))


def load_searcher(experiment_path: str | Path) -> ConstrainedOptunaSearch:
    """The searcher as last checkpointed in a (local) experiment folder."""
    searcher = ConstrainedOptunaSearch()
    searcher.restore_from_dir(str(experiment_path))
    return searcher


class BatchHalving(FIFOScheduler):
    """Deterministic successive halving for batched studies: a trial of batch ``k`` is stopped
    after its screening when its score is below the median of the screening scores of the
    trials of batches ``0 .. k-1`` (all finished before batch ``k`` was suggested), whatever
    order the trials of its own batch finish in. The first batch is never stopped.

    The scores are read from the trials' last results (:data:`SCREENED`), so the rule holds
    after ``Tuner.restore`` without any state of its own.
    """

    def __init__(self, batch_size: int) -> None:
        super().__init__()
        self.batch_size = batch_size

    def on_trial_result(self, tune_controller: Any, trial: Any, result: dict) -> str:
        if result.get(ROUND) != 1 or result.get("phase") != "screened":
            return TrialScheduler.CONTINUE
        number = trial.config.get(NUMBER)
        if number is None:
            return TrialScheduler.CONTINUE
        start = (int(number) // self.batch_size) * self.batch_size
        earlier = []
        for other in tune_controller.get_trials():
            n = other.config.get(NUMBER)
            score = (other.last_result or {}).get(SCREENED)
            if n is not None and int(n) < start and isinstance(score, int | float):
                earlier.append(float(score))
        return halving_decision(float(result[SCORE]), earlier)


def halving_decision(score: float, earlier: list[float]) -> str:
    """``STOP`` when ``score`` is below the median of the finite ``earlier`` scores.

    >>> halving_decision(1.0, []), halving_decision(1.0, [0.0, 2.0, 3.0])
    ('CONTINUE', 'STOP')
    """
    finite = [x for x in earlier if math.isfinite(x)]
    if finite and math.isfinite(score) and score < float(np.median(finite)):
        return TrialScheduler.STOP
    return TrialScheduler.CONTINUE


def make_scheduler(spec: StudySpec) -> TrialScheduler:
    """Successive halving on the screening round when the study screens, else FIFO.

    Rung 1 is the screened score. Batched (``spec.batch_size``): :class:`BatchHalving`.
    Otherwise Tune's ASHA: a trial is stopped when its score is below the median of the
    scores recorded at that rung so far (reduction factor 2; which those are depends on the
    order trials finish in); round 2 is the end.
    """
    if not spec.screens:
        return FIFOScheduler()
    if spec.batch_size is not None:
        return BatchHalving(spec.batch_size)
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


# --- the copy's check ---------------------------------------------------------------------------


def check_optuna_copy(plan: StudyPlan, experiment_path: str, *, finished: bool = True) -> None:
    """A finished study's Optuna copy (``optuna.db`` by default) must be whole and its own:
    the study of this name with every trial. A missing local copy is written again from the
    Tune experiment's searcher, with the final winner of ``best.json`` marked. An unfinished
    study's copy (``finished=False``, checked before a resume) may lack trials, or be missing
    (the searcher writes it again).

    Raises:
        ValueError: one line naming the file and the problem (corrupt, cut short, another
            study's, trials missing).
    """
    url, name = plan.optuna_url, plan.spec.name
    prefix = "sqlite:///"
    if not url.startswith(prefix):
        return  # a shared database: checked by its own server
    path = Path(url.removeprefix(prefix))
    if not path.exists():
        if finished and experiment_path and not is_uri(experiment_path):
            searcher = load_searcher(experiment_path)
            searcher._export_to = url
            searcher.export()
            best = json.loads((plan.out / "best.json").read_text())
            mark_final_winner(url, name, best.get("trial_id"), bool(best.get("feasible")))
        return
    problem = optuna_copy_problem(path, name, plan.spec.trials, at_most=not finished)
    if problem:
        raise ValueError(
            f"{path}: {problem}; it is only a copy for Optuna's tools: delete it and rerun the "
            "same command to write it again from the study's Tune experiment"
        )


def optuna_copy_problem(path: Path, name: str, trials: int, *, at_most: bool = False) -> str:
    """What is wrong with the Optuna SQLite copy at ``path`` of study ``name`` with ``trials``
    trials (``at_most``: up to ``trials``, a study under way) (``""``: nothing). Opened
    read-only: nothing is created or changed."""
    import sqlite3

    try:
        with contextlib.closing(sqlite3.connect(f"file:{path}?mode=ro", uri=True)) as db:
            rows = db.execute("SELECT study_id FROM studies WHERE study_name = ?", (name,))
            found = rows.fetchall()
            if not found:
                names = [r[0] for r in db.execute("SELECT study_name FROM studies")]
                return f"holds no study {name!r} (it holds {names or 'none'}): not this study's"
            (n,) = db.execute(
                "SELECT COUNT(*) FROM trials WHERE study_id = ?", (found[0][0],)
            ).fetchone()
            check = db.execute("PRAGMA quick_check").fetchone()
    except sqlite3.Error as e:
        return f"not a whole Optuna database ({e})"
    if check and check[0] != "ok":
        return f"a damaged Optuna database ({check[0]})"
    if n > trials or (n != trials and not at_most):
        return f"holds {n} trials of study {name!r}, the study has {trials}"
    return ""
