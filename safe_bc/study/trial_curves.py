"""A study's curves in TensorBoard, one run per trial with a name a person reads.

``results/<study>/tensorboard/<run>/`` holds, for each trial, run ``t003_eps1.2_alpha0.45_…``
(its trial number, then its sampled settings):

* ``bc/train_loss`` (and ``bc/val_loss`` with a validation set, ``bc/samples``,
  ``bc/seconds``) at every logged batch, from the trial's ``bc/curve.parquet``
  (``bc_seed_<s>/…`` for its further training seeds);
* ``eval/<metric>`` at each evaluation round (step 1 the screening, 2 the rest of its tracks):
  the reward and its lower bound, the safety mean, the crossings of ``d_s`` (``violation_rate``,
  ``any_violation``, ``violation_share_ucb``), the deferred share and every constraint;
* ``<stage>/<column>`` for each stage the study runs (e.g. ``selfimprove/…`` per round);
* once the trials are in, an entry of the HParams view: the settings, the trial's status,
  feasibility and whether it is the winner, with the objective, every constraint,
  ``feasible`` and ``winner`` as its metrics (rewritten with the final phase's winner).

Each final-phase candidate's retrained agents add run ``final_<run>_seed<s>`` (plain BC:
``final_plain_bc_seed<s>``) with its ``bc/*`` curve. The runs are written from the study's own
tables (history, trial folders), so they change nothing that a study computes; the live
:class:`TrialCurves` callback rewrites a trial's run after each of its reports.

The names and rows are pure functions (:func:`run_name`, :func:`eval_scalars`,
:func:`hparams_entry`); the writers read the trial folders and write the event files.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import pandas as pd
from ray import tune

from safe_bc.data.curves import table_scalars, write_scalars
from safe_bc.methods.rounds import ROUND_CURVE

BOARD = "tensorboard"
"""The folder in ``results/<study>/`` that ``tensorboard --logdir`` is pointed at."""

EVAL_METRICS = (
    "reward_mean",
    "reward_lcb",
    "safety_mean",
    "violation_steps",
    "violation_rate",
    "any_violation",
    "violation_share_ucb",
    "deferred_share",
    "constraint_safety",
    "constraint_violation",
    "constraint_deferral",
    "constraint",
    "episodes",
)
"""A trial's report keys written as ``eval/<key>`` at each evaluation round."""

ROUND = "eval_round"
"""The report key of the evaluation round (:data:`safe_bc.study.search.ROUND`)."""
NUMBER = "trial_number"
"""The report/config key of the trial's number (:data:`safe_bc.study.search.NUMBER`)."""
MAX_NAME = 100
"""Longest run name: the settings past it are cut (the HParams entry has them all)."""


def short(value: Any) -> str:
    """A setting's value as a run name spells it.

    >>> short(0.000312345), short(2.0), short((16, 32, 32)), short("all"), short(True)
    ('0.000312', '2', '16-32-32', 'all', 'True')
    """
    if isinstance(value, bool):
        return str(value)
    if isinstance(value, float):
        return f"{value:.3g}"
    if isinstance(value, list | tuple):
        return "-".join(short(v) for v in value)
    return str(value).replace("/", "-").replace(" ", "")


def run_name(number: Any, params: Mapping[str, Any], trial_id: str = "") -> str:
    """``t<number>_<setting><value>…``: the trial's number (3 digits) and its sampled settings
    by their last name, at most :data:`MAX_NAME` characters; a trial without a number (a
    searcher without batches) is ``t_<trial id>…``.

    >>> run_name(3, {"selection.eps": 1.23456, "selection.alpha": 0.5, "bc.network.hidden": 64})
    't003_eps1.23_alpha0.5_hidden64'
    >>> run_name(None, {"selection.alpha": 0.5}, "ab12")
    't_ab12_alpha0.5'
    """
    known = number is not None and not _missing(number)
    name = f"t{int(number):03d}" if known else f"t_{trial_id}"
    for key, value in params.items():
        part = f"_{key.rsplit('.', 1)[-1]}{short(value)}"
        if len(name) + len(part) > MAX_NAME:
            break
        name += part
    return name


def run_names(trials: pd.DataFrame, params: Sequence[str]) -> dict[str, str]:
    """Trial id -> run name (:func:`run_name`), for every row of the trial table."""
    out = {}
    for row in trials.to_dict(orient="records"):
        tid = str(row["trial_id"])
        out[tid] = run_name(row.get(NUMBER), {k: row.get(k) for k in params}, tid)
    return out


def _missing(value: Any) -> bool:
    return isinstance(value, float) and math.isnan(value)


def _number(value: Any) -> float | None:
    """A finite number from a report value (``None``: text, missing or not finite)."""
    if isinstance(value, bool):
        return float(value)
    try:
        v = float(value)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def eval_scalars(reports: pd.DataFrame) -> pd.DataFrame:
    """The ``eval/<metric>`` rows (``tag``, ``step``, ``value``) of one trial's reports: one
    step per evaluation round (the last report of a round counts), NaN left out.

    >>> r = pd.DataFrame({"eval_round": [0, 1, 2], "reward_mean": [float("nan"), 800.0, 850.0],
    ...                   "episodes": [0, 3, 10]})
    >>> for row in eval_scalars(r).values.tolist():
    ...     print(row)
    ['eval/reward_mean', 1, 800.0]
    ['eval/episodes', 1, 3.0]
    ['eval/reward_mean', 2, 850.0]
    ['eval/episodes', 2, 10.0]
    """
    if reports.empty or ROUND not in reports:
        return pd.DataFrame(columns=["tag", "step", "value"])
    rounds = pd.to_numeric(reports[ROUND], errors="coerce")
    done = reports[rounds >= 1].assign(_r=rounds[rounds >= 1].astype(int))
    done = done.drop_duplicates("_r", keep="last").sort_values("_r", kind="stable")
    rows = []
    for row in done.to_dict(orient="records"):
        for key in EVAL_METRICS:
            v = _number(row.get(key))
            if v is not None:
                rows.append((f"eval/{key}", int(row["_r"]), v))
    return pd.DataFrame(rows, columns=["tag", "step", "value"])


def hparams_entry(
    row: Mapping[str, Any],
    params: Sequence[str],
    objective: str,
    winner: str | None,
    final: Mapping[str, Any] | None = None,
) -> tuple[dict[str, Any], dict[str, float]]:
    """The HParams entry of one trial (its row of the trial table): ``(settings, metrics)``.
    Settings: the sampled parameters (tuples as text), ``trial`` (its number), ``status``,
    ``feasible`` and ``winner``; metrics ``hparams/<objective>``, ``hparams/constraint`` and
    each constraint (``<= 0``: met), ``hparams/feasible`` and ``hparams/winner`` (1 or 0),
    those without a finite value left out; with ``final`` (the trial's row of the final
    phase's table, a candidate) also ``hparams/final_reward`` and ``hparams/final_constraint``
    on the fresh tracks.

    >>> hp, m = hparams_entry({"trial_id": "a1", "trial_number": 2, "status": "done",
    ...     "selection.alpha": 0.5, "feasible": True, "reward_lcb": 880.0, "constraint": -0.1},
    ...     ["selection.alpha"], "reward_lcb", "a1")
    >>> hp
    {'selection.alpha': 0.5, 'trial': 2, 'status': 'done', 'feasible': True, 'winner': True}
    >>> sorted(m.items())  # doctest: +NORMALIZE_WHITESPACE
    [('hparams/constraint', -0.1), ('hparams/feasible', 1.0), ('hparams/reward_lcb', 880.0),
     ('hparams/winner', 1.0)]
    """
    settings: dict[str, Any] = {}
    for key in params:
        v = row.get(key)
        if hasattr(v, "item") and not isinstance(v, str | bytes):
            v = v.item()  # a numpy number from the table
        if isinstance(v, bool | int | float | str) and not _missing(v):
            settings[key] = v
        else:
            settings[key] = short(v) if v is not None and not _missing(v) else ""
    number = row.get(NUMBER)
    feasible = bool(row.get("feasible")) if not _missing(row.get("feasible")) else False
    is_winner = winner is not None and str(row.get("trial_id")) == winner
    settings.update(
        trial=-1 if number is None or _missing(number) else int(number),
        status=str(row.get("status", "")),
        feasible=feasible,
        winner=is_winner,
    )
    metrics: dict[str, float] = {}
    for key in (objective, "constraint", "constraint_safety", "constraint_violation",
                "constraint_deferral"):  # fmt: skip
        v = _number(row.get(key))
        if v is not None:
            metrics[f"hparams/{key}"] = v
    metrics["hparams/feasible"] = float(feasible)
    metrics["hparams/winner"] = float(is_winner)
    for key in ("reward", "constraint") if final is not None else ():
        v = _number(final.get(key))
        if v is not None:
            metrics[f"hparams/final_{key}"] = v
    return settings, metrics


def hparams_scalars(metrics: Mapping[str, float]) -> pd.DataFrame:
    """The HParams entry's metrics as scalars at step 0 (the view reads them from the run)."""
    return pd.DataFrame(
        [(k, 0, float(v)) for k, v in metrics.items()], columns=["tag", "step", "value"]
    )


# --- reading the trial folders, writing the runs ------------------------------------------------


def _read(path: Path) -> pd.DataFrame | None:
    from safe_bc.data.store import DatasetError, read_table

    if not path.exists():
        return None
    try:
        return read_table(path)[0]
    except (DatasetError, OSError):
        return None


def folder_scalars(folder: Path | None, stages: Sequence[str] = ()) -> pd.DataFrame:
    """The curves a trial wrote into its folder: ``bc/*`` (``bc_seed_<s>/*``) at each logged
    batch, ``<stage>/*`` at each iteration of each stage of ``stages`` (its
    ``curve.parquet``, else ``history.parquet``) and ``<stage>/round_<r>/bc/*`` at each logged
    batch of a round's retraining; empty without a folder."""
    parts = []
    if folder is not None and folder.is_dir():
        from safe_bc.bc.checkpoint import CURVE

        for sub in sorted(folder.glob("bc*")):
            if sub.name == "bc" or sub.name.startswith("bc_seed_"):
                table = _read(sub / CURVE)
                if table is not None and "batch" in table:
                    parts.append(table_scalars(table, "batch", sub.name))
        for name in stages:
            for file in (CURVE, "history.parquet"):
                table = _read(folder / name / file)
                if table is not None and "iteration" in table:
                    parts.append(table_scalars(table, "iteration", name))
                    break
            for path in sorted((folder / name).glob(f"round_*/{ROUND_CURVE}")):
                table = _read(path)  # a round's retraining (self-imitation, queries)
                if table is not None and "batch" in table:
                    round_name = path.relative_to(folder / name).parts[0]
                    parts.append(table_scalars(table, "batch", f"{name}/{round_name}/bc"))
    parts = [p for p in parts if len(p)]
    if not parts:
        return pd.DataFrame(columns=["tag", "step", "value"])
    return pd.concat(parts, ignore_index=True)


def write_trial_run(
    board: Path,
    name: str,
    folder: Path | None,
    reports: pd.DataFrame,
    stages: Sequence[str] = (),
    hparams: tuple[dict[str, Any], dict[str, float]] | None = None,
    metric_names: Sequence[str] = (),
) -> Path:
    """Write one trial's run ``board/name``: its folder's curves, its evaluation rounds and,
    with ``hparams``, its HParams entry (whose column list names ``metric_names``, else the
    entry's own metrics: TensorBoard takes the columns of one run for all). Returns the run's
    folder."""
    parts = [folder_scalars(folder, stages), eval_scalars(reports)]
    if hparams is not None:
        parts.append(hparams_scalars(hparams[1]))
    parts = [p for p in parts if len(p)]
    scalars = (
        pd.concat(parts, ignore_index=True)
        if parts
        else pd.DataFrame(columns=["tag", "step", "value"])
    )
    summary = None
    if hparams is not None:
        summary = (hparams[0], {k: 0.0 for k in (metric_names or hparams[1])})
    write_scalars(board / name, scalars, summary)
    return board / name


def write_board(
    out: Path,
    trials: pd.DataFrame,
    history: pd.DataFrame,
    *,
    params: Sequence[str],
    objective: str,
    stages: Sequence[str] = (),
    exp_path: str | None = None,
    winner: str | None = None,
    final: pd.DataFrame | None = None,
) -> Path:
    """Every trial's run in ``out/tensorboard/`` with its HParams entry (``winner``: the trial
    id the study chose, ``None`` while it has none); ``exp_path``: the Tune experiment's local
    folder holding the trials' folders (``None``: a remote storage, no ``bc/*`` curves);
    ``final``: the final phase's table (its candidates' values on the fresh tracks).
    Returns the board's folder."""
    board = Path(out) / BOARD
    names = run_names(trials, params)
    by_trial = (
        dict(tuple(history.groupby("trial_id", sort=False)))
        if len(history) and "trial_id" in history
        else {}
    )
    finals = (
        {str(r["method"]): r for r in final.to_dict(orient="records")}
        if final is not None and "method" in final
        else {}
    )
    rows = trials.to_dict(orient="records")
    entries = {
        str(row["trial_id"]): hparams_entry(
            row, params, objective, winner, finals.get(str(row["trial_id"]))
        )
        for row in rows
    }
    columns = list(dict.fromkeys(k for _, metrics in entries.values() for k in metrics))
    for tid, entry in entries.items():
        folder = None if exp_path is None else Path(exp_path) / f"trial_{tid}"
        reports = by_trial.get(tid, pd.DataFrame())
        write_trial_run(board, names[tid], folder, reports, stages, entry, columns)
    return board


def final_run_name(method: str, seed: int, names: Mapping[str, str]) -> str:
    """The run of a final-phase agent: ``final_<trial's run>_seed<s>`` (a method that is not a
    trial, e.g. plain BC: its own name).

    >>> final_run_name("a1", 2, {"a1": "t003_alpha0.5"}), final_run_name("plain BC", 1, {})
    ('final_t003_alpha0.5_seed2', 'final_plain_BC_seed1')
    """
    label = names.get(method, "_".join(str(method).replace("/", " ").split()))
    return f"final_{label}_seed{seed}"


def write_final_curve(board: Path, name: str, curve: pd.DataFrame) -> Path:
    """A final-phase agent's learning curve (:meth:`safe_bc.bc.train.TrainResult.curve`) as run
    ``board/name`` (``bc/*`` at each logged batch)."""
    write_scalars(board / name, table_scalars(curve, "batch", "bc"))
    return board / name


class TrialCurves(tune.Callback):
    """Rewrites a trial's run in the board after each of its reports (in the driver), so that
    TensorBoard shows the study while it runs; the trial tables' :func:`write_board` rewrites
    every run with its HParams entry. A write that fails is skipped (the next one, or the
    tables', writes the run whole)."""

    def __init__(self, board: str, params: Sequence[str], stages: Sequence[str] = ()) -> None:
        self.board = board
        self.params = tuple(params)
        self.stages = tuple(stages)
        self._reports: dict[str, list[dict[str, Any]]] = {}

    def on_trial_result(self, iteration: int, trials: list, trial: Any, result: dict, **info):
        rows = self.__dict__.setdefault("_reports", {}).setdefault(trial.trial_id, [])
        rows.append({k: result.get(k) for k in (ROUND, *EVAL_METRICS)})
        config = trial.config or {}
        params = {k: config.get(k) for k in self.params}
        name = run_name(config.get(NUMBER), params, trial.trial_id)
        path = getattr(trial, "path", None)
        folder = Path(path) if path and "://" not in str(path) else None
        with contextlib.suppress(OSError, ValueError):
            write_trial_run(Path(self.board), name, folder, pd.DataFrame(rows), self.stages)
