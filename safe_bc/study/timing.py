"""Where a study's wall-clock goes: the time table of ``results/<study>/timing.parquet``.

Pure: the driver (:func:`safe_bc.study.run.run_study`) records what it timed as plain
records, one per timed piece, ``{"run", "phase", "seconds"}`` (on the tuning loop's record
also ``"slots"``, the trials that may run at once, resolved from the cluster's CPUs, and
``"running"``, the most that did), appended to ``timing.jsonl`` as each piece
ends; every driver run of the study (a resumed study has several) adds its own. A run's
``"total"`` record is its wall-clock from start to end; a run killed before writing it
counts the sum of its pieces. :func:`timing_table` adds them up with the trials' own
seconds (their last reports: :func:`trial_parts`).

Two views in one table (column ``part_of``):

* ``study``: the driver's phases (:data:`PHASES`), seconds and share of the total
  wall-clock; the shares sum to 1 (``other``: what no phase covers).
* ``tuning slots``: the tuning loop's capacity, its wall-clock x the concurrent slots
  (``max_concurrent``), split into the trials' busy seconds (training, stages, evaluation,
  checkpoints and stored rounds, the rest of each trial) and ``idle_and_overhead``,
  capacity - busy (never negative): slots left empty (a batch waiting for its last trial,
  too few CPUs) and Ray's own cost (scheduling, actor start-up, reports). The shares sum
  to 1.

The ``tuning`` row's ``count`` is the concurrency reached: the most trials seen running at
once (over the study's driver runs; empty for runs recorded before it was counted).

The ``optuna_copy`` row (``part_of`` ``tuning``) is the driver's time copying the Optuna
study after every batch (inside the tuning loop's wall-clock; share of it).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import pandas as pd

from safe_bc.methods.stages import stage_metrics

PHASES: dict[str, str] = {
    "ray_start": "starting or joining Ray",
    "demos": "loading (or collecting) the demonstrations",
    "tuning": "the tuning loop (Tune's fit: every trial, Optuna, the halving)",
    "trial_tables": "writing trials/history.parquet and pareto.png",
    "final_checkpoints": "choosing the candidates and loading their checkpoints",
    "final_train": "final phase: retraining the candidates and plain BC",
    "final_stages": "final phase: the study's stages on every candidate",
    "final_evaluation": "final phase: evaluating on the fresh tracks",
    "final_summary": "final phase: the summaries and the winner",
    "final_tables": "writing final*.parquet, best.json, pareto.png",
    "certification": "the winner on its own fresh tracks, and writing recommender/",
    "other": "the rest of the driver (checks, the Tuner's set-up and restore)",
}
"""The driver's phases, in order, and what each covers."""


def stage_seconds() -> tuple[str, ...]:
    """The registered stages' seconds in a trial's report
    (:func:`safe_bc.methods.stages.stage_metrics`)."""
    return tuple(k for k in stage_metrics() if k.endswith("_seconds"))


def trial_parts() -> dict[str, tuple[tuple[str, ...], str]]:
    """Busy parts of the trials: row -> (the trial report's columns summed, what it is), the
    stages' columns read from the registry when the table is made. The rest of the trials'
    ``duration_s`` is ``trial_other`` (demonstrations, selection, frame preprocessing,
    set-up)."""
    return {
        "trial_train": (("train_seconds",), "trials: the training loops"),
        "trial_stages": (stage_seconds(), "trials: the study's stages"),
        "trial_evaluation": (("eval_seconds",), "trials: evaluation rounds"),
        "trial_storage": (("store_seconds",), "trials: checkpoints and stored rounds"),
    }


TOTAL = "total"
"""Phase name of a run's whole wall-clock record."""
COPY = "optuna_copy"
"""Phase name of one copy of the Optuna study (one per batch, in the tuning loop)."""

COLUMNS = ("phase", "part_of", "seconds", "share", "count", "what")


def _sum(trials: pd.DataFrame, columns: Iterable[str]) -> float:
    total = 0.0
    for c in columns:
        if c in trials:
            values = pd.to_numeric(trials[c], errors="coerce").fillna(0.0)
            total += float(values.clip(lower=0).sum())
    return total


def timing_table(records: Sequence[Mapping[str, Any]], trials: pd.DataFrame) -> pd.DataFrame:
    """The time table of a study (see the module docstring) from the driver's ``records`` and
    the trial table ``trials`` (one row per trial, its last report).

    >>> recs = [{"run": "a", "phase": "tuning", "seconds": 10.0, "slots": 2},
    ...         {"run": "a", "phase": "total", "seconds": 12.0}]
    >>> t = timing_table(recs, pd.DataFrame({"train_seconds": [6.0], "duration_s": [8.0]}))
    >>> t.set_index("phase").loc[["tuning", "other", "trial_other", "idle_and_overhead"],
    ...                           "seconds"].tolist()
    [10.0, 2.0, 2.0, 12.0]
    """
    by_run: dict[str, list[Mapping[str, Any]]] = {}
    for r in records:
        by_run.setdefault(str(r.get("run", "")), []).append(r)
    phase_s = dict.fromkeys(PHASES, 0.0)
    total = capacity = copy_s = 0.0
    copies = 0
    running: int | None = None
    for recs in by_run.values():
        run_parts = 0.0
        run_total = None
        for r in recs:
            phase, seconds = str(r["phase"]), max(float(r["seconds"]), 0.0)
            if phase == TOTAL:
                run_total = seconds if run_total is None else max(run_total, seconds)
            elif phase == COPY:
                copy_s += seconds
                copies += 1
            elif phase in phase_s and phase != "other":
                phase_s[phase] += seconds
                run_parts += seconds
                if phase == "tuning":
                    capacity += seconds * max(int(r.get("slots", 1)), 1)
                    if r.get("running") is not None:
                        running = max(running or 0, int(r["running"]))
        total += run_parts if run_total is None else max(run_total, run_parts)
    phase_s["other"] = max(total - sum(phase_s.values()), 0.0)

    rows = [
        (p, "study", s, s / total if total > 0 else math.nan,
         running if p == "tuning" else None, PHASES[p])
        for p, s in phase_s.items()
    ]  # fmt: skip
    n = len(trials)
    busy_parts = trial_parts()
    parts = {name: _sum(trials, cols) for name, (cols, _) in busy_parts.items()}
    duration = _sum(trials, ["duration_s"])
    parts["trial_other"] = max(duration - sum(parts.values()), 0.0)
    busy = sum(parts.values())
    parts["idle_and_overhead"] = max(capacity - busy, 0.0)
    whole = max(capacity, busy)
    what = {name: text for name, (_, text) in busy_parts.items()}
    what["trial_other"] = "trials: the rest (data, selection, set-up, reports)"
    what["idle_and_overhead"] = "empty slots and Ray's overhead: wall x slots - busy"
    for name, s in parts.items():
        count = None if name == "idle_and_overhead" else n
        rows.append((name, "tuning slots", s, s / whole if whole > 0 else math.nan, count,
                     what[name]))  # fmt: skip
    tuning = phase_s["tuning"]
    rows.append((COPY, "tuning", copy_s, copy_s / tuning if tuning > 0 else math.nan, copies,
                 "the driver copying the Optuna study (once per batch)"))  # fmt: skip
    table = pd.DataFrame(rows, columns=list(COLUMNS))
    table["count"] = table["count"].astype("Int64")
    return table


def timing_lines(table: pd.DataFrame) -> list[str]:
    """A few lines for the console: the total, the largest phases, the tuning loop's use of
    its slots and the Optuna copies.

    >>> recs = [{"run": "a", "phase": "tuning", "seconds": 10.0, "slots": 2, "running": 2},
    ...         {"run": "a", "phase": "optuna_copy", "seconds": 0.5},
    ...         {"run": "a", "phase": "total", "seconds": 12.0}]
    >>> t = timing_table(recs, pd.DataFrame({"train_seconds": [6.0], "duration_s": [8.0]}))
    >>> print("\\n".join(timing_lines(t)))
    time: 12 s in all; tuning 10 s (83%), other 2 s (17%)
    tuning loop, wall x 2 slots (most running: 2) = 20 s: train 6 s (30%), other 2 s (10%)
      idle slots and Ray's overhead: 12 s (60%)
    Optuna copies: 1, 0.5 s in all (0.50 s each)
    """
    t = table.set_index("phase")
    study = t[(t["part_of"] == "study") & (t["seconds"] > 0)]
    study = study.sort_values("seconds", ascending=False)
    total = float(t.loc[t["part_of"] == "study", "seconds"].sum())

    def cells(rows: pd.DataFrame, prefix: str = "") -> str:
        return ", ".join(
            f"{p.removeprefix(prefix)} {r.seconds:.0f} s ({r.share:.0%})"
            for p, r in rows.iterrows()
        )

    lines = [f"time: {total:.0f} s in all; {cells(study.head(4))}"]
    slots = t[t["part_of"] == "tuning slots"]
    whole = float(slots["seconds"].sum())
    if whole > 0:
        busy = slots[(slots.index != "idle_and_overhead") & (slots["seconds"] > 0)]
        tuning = float(t.loc["tuning", "seconds"])
        n = f"{whole / tuning:.0f}" if tuning > 0 else "?"
        seen = t.loc["tuning", "count"]
        most = "" if pd.isna(seen) else f" (most running: {int(seen)})"
        lines.append(f"tuning loop, wall x {n} slots{most} = {whole:.0f} s: "
                     f"{cells(busy, 'trial_')}")  # fmt: skip
        idle = t.loc["idle_and_overhead"]
        lines.append(f"  idle slots and Ray's overhead: {idle.seconds:.0f} s ({idle.share:.0%})")
    copies = int(t.loc[COPY, "count"]) if COPY in t.index else 0
    if copies:
        s = float(t.loc[COPY, "seconds"])
        lines.append(f"Optuna copies: {copies}, {s:.1f} s in all ({s / copies:.2f} s each)")
    return lines


def timing_markdown(table: pd.DataFrame, note: str = "") -> str:
    """``timing.md``: the table (``DataFrame.to_markdown``), how to read it, and ``note``
    (the command and the provenance)."""
    view = table.assign(
        seconds=[f"{s:.1f}" for s in table["seconds"]],
        share=["" if pd.isna(s) else f"{s:.1%}" for s in table["share"]],
        count=["" if pd.isna(c) else str(int(c)) for c in table["count"]],
    )
    lines = [
        "# Where the study's time went",
        "",
        "Rows `part_of = study` split the driver's wall-clock (every run of the study added "
        "up); their shares sum to 100%. Rows `part_of = tuning slots` split the tuning loop's "
        "capacity, its wall-clock x the concurrent slots: the trials' busy seconds (summed "
        "over trials) and `idle_and_overhead` = capacity - busy (empty slots, Ray's own "
        "cost). `optuna_copy` is the driver's copy of the Optuna study after each batch, "
        "inside the tuning loop (its share is of the tuning wall-clock).",
        "",
        view.to_markdown(index=False, disable_numparse=True),
    ]
    if note:
        lines += ["", note]
    return "\n".join(lines) + "\n"
