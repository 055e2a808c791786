"""What the default study's batch size costs on 2 cores and buys on 16, replayed from the
committed trials.

Usage::

    python -m scripts.cluster_schedule      # writes results/checks/batch_schedule.{parquet,md}

For each committed run of ``tune_jobs/default.py`` (``results/default`` and its replicates
``results/default/replicates/r*``: 16 trials in batches of 2, 1 CPU each) the trials'
durations are replayed at other batch sizes on 2 and 16 slots
(:func:`safe_bc.study.spec.schedule_seconds`: a batch starts when the previous one has finished;
Ray's start-up and overhead left out). The batch size also changes which trials the halving
stops (:class:`safe_bc.study.search.BatchHalving`: a trial is compared with the earlier
batches only, the first batch never stopped), so it is replayed on the committed screening
scores: a stopped trial lasts its screened duration, a continued one its full duration (for a
trial stopped in the committed run, its screened duration plus its screening's evaluation
seconds per episode times the episodes it skipped). The replay at batch 2 must give the
committed stops (checked). Same trials at every batch size: that a larger batch makes TPE
suggest other trials (informed by fewer results) is counted (``tpe_trials``,
``results_per_tpe_trial``) but its effect on the search's outcome is not measured.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from safe_bc.data.atomic import write_text_atomic
from safe_bc.data.provenance import run_metadata
from safe_bc.data.store import read_table, write_table_atomic
from safe_bc.study.search import halving_decision
from safe_bc.study.spec import schedule_seconds

BATCHES = (2, 4, 8, 16)
"""Batch sizes replayed."""
SLOTS = (2, 16)
"""Trials at once replayed: the 2-core laptop, a 16-CPU machine."""


def sources(root: Path) -> list[Path]:
    """The committed runs of the default study: ``root`` and its replicates."""
    return [root, *sorted((root / "replicates").glob("r*"))]


def trial_times(folder: Path) -> tuple[pd.DataFrame, dict[str, Any]]:
    """One row per trial, in trial order: ``screened_s`` (start to the end of its screening),
    ``full_s`` (start to the end of its full evaluation, estimated for a trial stopped in the
    run), ``score`` (its screening score), ``stopped`` (in the run); and the study spec."""
    trials, meta = read_table(folder / "trials.parquet")
    history, _ = read_table(folder / "history.parquet")
    spec = meta["study"]
    rows = []
    for t in trials.sort_values("trial_number").itertuples():
        h = history[history["trial_id"] == t.trial_id]
        screened = h[h["phase"] == "screened"].tail(1)
        duration = float(t.duration_s)
        if screened.empty:  # not screened (invalid, or no screening): one duration
            rows.append((int(t.trial_number), duration, duration, np.nan, False))
            continue
        s = screened.iloc[0]
        stopped = t.status == "stopped"
        if stopped:
            per_episode = float(s["eval_seconds"]) / float(s["episodes"])
            skipped = (spec["eval_episodes"] - spec["screen_episodes"]) * spec["train_seeds"]
            full = duration + per_episode * skipped
            screened_s = duration
        else:
            full, screened_s = duration, float(s["time_total_s"])
        rows.append((int(t.trial_number), screened_s, full, float(s["score"]), stopped))
    cols = ["trial_number", "screened_s", "full_s", "score", "stopped"]
    return pd.DataFrame(rows, columns=cols), spec


def replay_stops(scores: np.ndarray, batch: int) -> np.ndarray:
    """Which trials :class:`BatchHalving` stops at this batch size, on these screening scores
    (NaN: never screened, never stopped)."""
    stops = np.zeros(len(scores), bool)
    for i, score in enumerate(scores):
        start = (i // batch) * batch
        earlier = [float(x) for x in scores[:start] if np.isfinite(x)]
        if np.isfinite(score):
            stops[i] = halving_decision(float(score), earlier) == "STOP"
    return stops


def tpe_counts(trials: int, batch: int, startup: int) -> tuple[int, float]:
    """Trials TPE suggests (the sampler has at least ``startup`` results when their batch is
    suggested; the others are random) and the mean results each of them was informed by."""
    seen = [(i // batch) * batch for i in range(trials)]
    informed = [s for s in seen if s >= startup]
    return len(informed), float(np.mean(informed)) if informed else 0.0


def replay(folder: Path, label: str) -> pd.DataFrame:
    """The rows of one committed run: one per batch size."""
    times, spec = trial_times(folder)
    n = len(times)
    scores = times["score"].to_numpy(float)
    committed = times["stopped"].to_numpy(bool)
    if not np.array_equal(replay_stops(scores, int(spec["batch_size"])), committed):
        raise AssertionError(f"{folder}: the halving replay does not give the committed stops")
    rows = []
    for b in BATCHES:
        stops = replay_stops(scores, b)
        durations = np.where(stops, times["screened_s"], times["full_s"]).tolist()
        wall = {k: schedule_seconds(durations, k, b) for k in SLOTS}
        tpe, seen = tpe_counts(n, b, int(spec["startup_trials"]))
        row = {"run": label, "batch_size": b, "trials": n, "stopped": int(stops.sum()),
               "trial_seconds": float(sum(durations)), "tpe_trials": tpe,
               "results_per_tpe_trial": seen}  # fmt: skip
        for k in SLOTS:
            row[f"wall_s_{k}_slots"] = wall[k]
            row[f"trials_per_min_{k}_slots"] = 60.0 * n / wall[k]
        row["speedup_16_vs_2"] = wall[2] / wall[16]
        rows.append(row)
    table = pd.DataFrame(rows)
    table["cost_2_slots_vs_batch_2"] = table["wall_s_2_slots"] / table["wall_s_2_slots"].iloc[0] - 1
    return table


PROPOSED = 8
"""The batch size proposed for ``tune_jobs/default.py`` (not applied yet)."""


def proposal(mean: pd.DataFrame) -> str:
    """The proposal paragraph, its numbers read from ``mean``."""
    m = mean.set_index("batch_size")
    p, two, full = m.loc[PROPOSED], m.loc[2], m.loc[16]
    return (
        f"**Proposed: batch {PROPOSED}** for the default study (not applied). On 2 cores it "
        f"costs {p['cost_2_slots_vs_batch_2']:+.0%} wall-clock against batches of 2 "
        f"({p['wall_s_2_slots']:.0f} s vs {two['wall_s_2_slots']:.0f} s: idle slots at each "
        f"batch's end, and {p['stopped']:.1f} instead of {two['stopped']:.1f} trials stopped by "
        f"the halving, whose first batch is never stopped); TPE suggests "
        f"{p['tpe_trials']:.0f} trials from {p['results_per_tpe_trial']:.0f} results each "
        f"(batches of 2: {two['tpe_trials']:.0f} trials from {two['results_per_tpe_trial']:.0f} "
        f"on average). On 16 CPUs 8 run at once: {p['speedup_16_vs_2']:.2f}x the 2-slot "
        f"rate at the same batch. Batches of 16 would reach {full['speedup_16_vs_2']:.2f}x but "
        f"make the 16-trial study a random search without screening "
        f"({full['cost_2_slots_vs_batch_2']:+.0%} on 2 cores). No batch size of a 16-trial "
        "study reaches 6x on these trials: a batch's wall-clock on 16 slots is its slowest "
        "trial. A study meant to run 16 at once needs batches of 16 and more than 16 trials "
        "(not replayed: the committed runs have 16)."
    )


def markdown(table: pd.DataFrame, mean: pd.DataFrame, note: str) -> str:
    def fmt(frame: pd.DataFrame) -> pd.DataFrame:
        out = frame.copy()
        for c in out.columns:
            if c.startswith("wall_s") or c == "trial_seconds":
                out[c] = [f"{v:.0f}" for v in out[c]]
            elif c.startswith("trials_per_min") or c in ("results_per_tpe_trial", "stopped",
                                                          "tpe_trials"):  # fmt: skip
                out[c] = [f"{v:.1f}" for v in out[c]]
            elif c == "speedup_16_vs_2":
                out[c] = [f"{v:.2f}x" for v in out[c]]
            elif c == "cost_2_slots_vs_batch_2":
                out[c] = [f"{v:+.0%}" for v in out[c]]
        return out

    return "\n".join([
        "# The default study's batch size: its cost on 2 cores, its ceiling on 16",
        "",
        "Replayed from the committed trials of `tune_jobs/default.py` (16 trials, 1 CPU each, "
        "run in batches of 2 on this 2-core machine) by `python -m scripts.cluster_schedule`"
        " (its docstring says how). Wall-clock of the tuning loop's trials on 2 and 16 slots, "
        "Ray's overhead left out: a ceiling, not a measurement. `stopped`: trials the halving "
        "stops after screening at that batch size (the first batch is never stopped), which "
        "changes the work (`trial_seconds`). `tpe_trials`: trials TPE suggests (6 startup "
        "trials are random) and `results_per_tpe_trial` the results it had when it did. "
        "Not measured: how much worse TPE's picks are with fewer results.",
        "",
        "## Mean over the committed runs",
        "",
        fmt(mean).to_markdown(index=False, disable_numparse=True),
        "",
        proposal(mean),
        "",
        "## Each run",
        "",
        fmt(table).to_markdown(index=False, disable_numparse=True),
        "",
        note,
        "",
    ])  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=Path, default=Path("results/default_two_seeds"))
    p.add_argument("--out", type=Path, default=Path("results/checks/batch_schedule.parquet"))
    args = p.parse_args(argv)
    folders = sources(args.runs)
    table = pd.concat(
        [replay(f, str(f.relative_to(args.runs.parent))) for f in folders], ignore_index=True
    )
    mean = table.drop(columns="run").groupby("batch_size", as_index=False).mean()
    meta = run_metadata(sources=[str(f) for f in folders], batch_sizes=list(BATCHES),
                        slots=list(SLOTS))  # fmt: skip
    write_table_atomic(args.out, table, meta)
    note = (f"Made by `python -m scripts.cluster_schedule` at revision "
            f"{meta['git_revision'][:12]} from {', '.join(meta['sources'])}.")  # fmt: skip
    text = markdown(table, mean, note)
    write_text_atomic(args.out.with_suffix(".md"), text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
