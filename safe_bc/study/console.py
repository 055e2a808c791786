"""What a study prints while Tune runs its trials: one line per finished trial by default,
Tune's status table every 30 s with ``--verbose``."""

from __future__ import annotations

import contextlib
import logging
import math
import sys
import warnings
from collections.abc import Iterator
from typing import Any

from ray import tune

from safe_bc.study.spec import OBJECTIVE, StudySpec, missed
from safe_bc.study.stop import stopping, tune_caught_signal


class StudyReporter(tune.CLIReporter):
    """Tune's status table, silent once a signal stops the study (its one line says so)."""

    def should_report(self, trials: list, done: bool = False) -> bool:
        return not stopping() and super().should_report(trials, done)


def progress_reporter(spec: StudySpec) -> tune.CLIReporter:
    """Tune's status table every 30 s: the objective, safety, feasibility and the parameters."""
    return StudyReporter(
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


def quiet_logs() -> None:
    """Tune's, Train's and Optuna's INFO lines (experiment state written, checkpoint created,
    study created) off: the trial lines and the summary say what a user needs."""
    import optuna

    for name in ("ray.tune", "ray.train"):
        logging.getLogger(name).setLevel(logging.WARNING)
    optuna.logging.set_verbosity(optuna.logging.WARNING)


TUNE_STOP_LINES = (
    "Stop signal received",
    "Experiment has been interrupted",
    "Training has been interrupted",
)
"""How Ray Tune's lines on a Ctrl-C start: its handler's notice and its advice to resume with
``Tuner.restore(...)`` (a study resumes by running the same command, as its own line says)."""


def _not_a_stop_line(record: logging.LogRecord) -> bool:
    if str(record.msg).startswith(TUNE_STOP_LINES[0]):  # Tune's handler caught a Ctrl-C
        tune_caught_signal()
    return not stopping() and not str(record.msg).startswith(TUNE_STOP_LINES)


TUNE_STOP_LOGGERS = ("ray.tune.tune", "ray.tune.analysis.experiment_analysis")
"""Where Tune's lines on a stop come from: the run's end (trials that "did not complete", the
run time), the result grid (metrics it cannot fetch for trials that had not reported yet)."""


def quiet_stop() -> None:
    """Ray Tune's lines on a Ctrl-C off: its notice and its advice always, everything of
    :data:`TUNE_STOP_LOGGERS` once a signal stops the study; its other warnings stay.
    Idempotent. Tune's handler logs its notice first thing (Ray 2.60), which is how
    :func:`stopping` learns of a Ctrl-C that Tune caught: ``ray.tune`` must log warnings."""
    for name in TUNE_STOP_LOGGERS:
        tune_logger = logging.getLogger(name)
        if _not_a_stop_line not in tune_logger.filters:
            tune_logger.addFilter(_not_a_stop_line)


FULL_DISK = "No space left on device"
"""How an ``ENOSPC`` reads (``strerror``): Tune's lines on a storage that filled up carry it."""
FULL_DISK_LOGGERS = (
    "ray.tune.execution.experiment_state",
    "ray.tune.execution.tune_controller",
    "ray.train._internal.syncer",
    *TUNE_STOP_LOGGERS,
)
"""Where Tune's lines on a full storage come from: its failed saves of the experiment state
(with their tracebacks), its trials' failures, its syncer, and the run's end."""


def is_full_disk(text: str) -> bool:
    """Whether ``text`` (a log line, an error) tells of a full storage (``ENOSPC``).

    >>> is_full_disk("OSError: [Errno 28] No space left on device"), is_full_disk("timeout")
    (True, False)
    """
    return FULL_DISK in text or "[Errno 28]" in text or "errno 28" in text


def _not_a_full_disk_line(record: logging.LogRecord) -> bool:
    text = record.getMessage()
    if record.exc_info and record.exc_info[1] is not None:
        text += f" {record.exc_info[1]}"
    if is_full_disk(text):
        _FULL_DISK_SEEN.append(True)
        return False
    return not (_FULL_DISK_SEEN and record.name in TUNE_STOP_LOGGERS)


_FULL_DISK_SEEN: list[bool] = []
"""Non-empty once a full storage was logged: the study stops on it in one line, so the run's
end (trials that "did not complete") is not logged either."""


def quiet_full_disk() -> None:
    """Ray Tune's lines on a full storage off (:data:`FULL_DISK_LOGGERS`): the study stops on
    it with one line of its own (:class:`safe_bc.study.run.HistoryRecorder`).
    Idempotent."""
    _FULL_DISK_SEEN.clear()
    for name in FULL_DISK_LOGGERS:
        tune_logger = logging.getLogger(name)
        if _not_a_full_disk_line not in tune_logger.filters:
            tune_logger.addFilter(_not_a_full_disk_line)


def trial_line(result: dict[str, Any], done: int, total: int) -> str:
    """One finished trial in one line.

    >>> r = {"trial_id": "ab12", "phase": "evaluated", "reward_mean": 905.12, "safety_mean": 7.3,
    ...      "any_violation": 0.0, "episodes": 15, "deferred_share": 0.041, "feasible": True,
    ...      "duration_s": 37.2}
    >>> for part in trial_line(r, 3, 16).split(", "):
    ...     print(part)
    trial 3/16 ab12: reward 905.1
    safety mean 7.30
    0/15 episodes beyond d_s
    4.1% deferred
    feasible (37 s)
    >>> trial_line({**r, "feasible": False, "constraint_deferral": 0.012}, 3, 16).split(", ")[-1]
    'infeasible: too many steps deferred (constraint_deferral +0.012) (37 s)'
    """
    tid = result.get("trial_id", "?")
    phase = result.get("phase", "")
    if phase == "invalid":
        return f"trial {done}/{total} {tid}: invalid ({result.get('error', '')})"
    n = int(result.get("episodes") or 0)
    share = float(result.get("any_violation", math.nan))
    beyond = "?" if math.isnan(share) else str(round(share * n))
    parts = [
        f"reward {float(result.get('reward_mean', math.nan)):.1f}",
        f"safety mean {float(result.get('safety_mean', math.nan)):.2f}",
        f"{beyond}/{n} episodes beyond d_s",
    ]
    deferred = result.get("deferred_share")
    if deferred is not None and not math.isnan(float(deferred)) and float(deferred) > 0:
        parts.append(f"{float(deferred):.1%} deferred")
    parts.append("feasible" if result.get("feasible") else "infeasible")
    if not result.get("feasible") and missed(result):
        parts[-1] += ": " + "; ".join(missed(result))
    stopped = " stopped by the screening:" if phase == "screened" else ":"
    seconds = float(result.get("duration_s", math.nan))
    return f"trial {done}/{total} {tid}{stopped} {', '.join(parts)} ({seconds:.0f} s)"


class TrialLines(tune.Callback):
    """Prints :func:`trial_line` as each trial finishes (the study's default console output);
    the count is of this driver run's finished trials."""

    def __init__(self, total: int) -> None:
        self.total = total
        self.done = 0

    def on_trial_complete(self, iteration: int, trials: list, trial: Any, **info: Any) -> None:
        self.done += 1
        print(trial_line(trial.last_result or {}, self.done, self.total), file=sys.stderr)

    def on_trial_error(self, iteration: int, trials: list, trial: Any, **info: Any) -> None:
        print(f"trial {trial.trial_id} failed; Tune retries it", file=sys.stderr)


@contextlib.contextmanager
def one_line_warnings() -> Iterator[None]:
    """Print each warning as one line, ``warning: <message>`` (whitespace folded), for the
    ``with`` block: a study's console is read line by line, and Python's own format adds the
    source line that warned."""
    before = warnings.formatwarning

    def fmt(message: Any, category: Any, filename: str, lineno: int, line: Any = None) -> str:
        return f"warning: {' '.join(str(message).split())}\n"

    warnings.formatwarning = fmt
    try:
        yield
    finally:
        warnings.formatwarning = before
