"""The study's time table (``safe_bc.study.timing``) from synthetic records: shares, the tuning
loop's idle slots and overhead, runs killed before their total."""

from __future__ import annotations

import math

import pandas as pd
import pytest

from safe_bc.study.timing import PHASES, timing_lines, timing_markdown, timing_table, trial_parts

SLOT_ROWS = [*trial_parts(), "trial_other", "idle_and_overhead"]


def _trials() -> pd.DataFrame:
    return pd.DataFrame(
        {
            "train_seconds": [10.0, 12.0, math.nan],  # the third was invalid: never trained
            "improve_seconds": [2.0, 3.0, math.nan],
            "eval_seconds": [20.0, 5.0, math.nan],
            "store_seconds": [1.0, 1.0, math.nan],
            "duration_s": [40.0, 25.0, 3.0],
        }
    )


def _records() -> list[dict]:
    first = [  # a run stopped after the tuning loop (Ctrl-C), its total written
        {"run": "a", "phase": "ray_start", "seconds": 4.0},
        {"run": "a", "phase": "demos", "seconds": 2.0},
        {"run": "a", "phase": "tuning", "seconds": 30.0, "slots": 2},
        {"run": "a", "phase": "optuna_copy", "seconds": 0.5},
        {"run": "a", "phase": "trial_tables", "seconds": 1.0},
        {"run": "a", "phase": "total", "seconds": 40.0},
    ]
    second = [  # the resumed run, to the end
        {"run": "b", "phase": "ray_start", "seconds": 3.0},
        {"run": "b", "phase": "tuning", "seconds": 20.0, "slots": 1},
        {"run": "b", "phase": "optuna_copy", "seconds": 0.7},
        {"run": "b", "phase": "optuna_copy", "seconds": 0.3},
        {"run": "b", "phase": "final_train", "seconds": 9.0},
        {"run": "b", "phase": "final_evaluation", "seconds": 6.0},
        {"run": "b", "phase": "total", "seconds": 41.0},
    ]
    return first + second


def test_time_table_splits_the_wall_clock_and_the_tuning_slots() -> None:
    t = timing_table(_records(), _trials()).set_index("phase")
    assert list(t.index) == [*PHASES, *SLOT_ROWS, "optuna_copy"]  # every phase, 0 if not run
    study = t[t["part_of"] == "study"]
    assert study["seconds"].sum() == pytest.approx(81.0)  # both runs' totals
    assert study["share"].sum() == pytest.approx(1.0)
    assert t.loc["ray_start", "seconds"] == 7.0 and t.loc["tuning", "seconds"] == 50.0
    assert t.loc["other", "seconds"] == pytest.approx(81.0 - (7 + 2 + 50 + 1 + 9 + 6))
    assert t.loc["final_stages", "seconds"] == 0.0

    slots = t[t["part_of"] == "tuning slots"]
    capacity = 30.0 * 2 + 20.0 * 1  # wall x slots of each run
    busy = 68.0  # the trials' duration_s (their parts are inside it)
    assert slots.loc["trial_train", "seconds"] == 22.0
    assert slots.loc["trial_stages", "seconds"] == 5.0  # improve_seconds
    assert slots.loc["trial_evaluation", "seconds"] == 25.0
    assert slots.loc["trial_storage", "seconds"] == 2.0
    assert slots.loc["trial_other", "seconds"] == pytest.approx(busy - 54.0)
    assert slots.loc["idle_and_overhead", "seconds"] == pytest.approx(capacity - busy)
    assert slots["share"].sum() == pytest.approx(1.0)
    assert slots["seconds"].sum() == pytest.approx(capacity)
    assert slots.loc["trial_train", "count"] == 3

    assert t.loc["optuna_copy", "seconds"] == pytest.approx(1.5)
    assert t.loc["optuna_copy", "count"] == 3
    assert t.loc["optuna_copy", "share"] == pytest.approx(1.5 / 50.0)


def test_overhead_is_never_negative_and_a_killed_run_counts_its_pieces() -> None:
    # the trials' seconds exceed the slots (e.g. a trial trained in a run whose tuning loop was
    # killed before its record): no negative overhead, the shares still sum to 1
    records = [
        {"run": "a", "phase": "ray_start", "seconds": 2.0},  # killed: no total
        {"run": "b", "phase": "tuning", "seconds": 10.0, "slots": 2},
        {"run": "b", "phase": "total", "seconds": 9.0},  # less than its pieces: the pieces
    ]
    t = timing_table(records, _trials()).set_index("phase")
    assert t.loc["idle_and_overhead", "seconds"] == 0.0
    assert t.loc["trial_other", "seconds"] >= 0.0
    slots = t[t["part_of"] == "tuning slots"]
    assert slots["share"].sum() == pytest.approx(1.0)
    study = t[t["part_of"] == "study"]
    assert study["seconds"].sum() == pytest.approx(12.0)
    assert (t["seconds"] >= 0).all() and t.loc["other", "seconds"] == 0.0
    assert study["share"].sum() == pytest.approx(1.0)


def test_time_table_reads_as_text() -> None:
    t = timing_table(_records(), _trials())
    md = timing_markdown(t, "Made by `safe-bc tune x`.")
    assert "| phase" in md and "idle_and_overhead" in md and md.rstrip().endswith("x`.")
    lines = timing_lines(t)
    assert lines[0].startswith("time: 81 s in all; tuning 50 s (62%)")
    assert any("idle slots and Ray's overhead: 12 s (15%)" in line for line in lines)
    assert lines[-1] == "Optuna copies: 3, 1.5 s in all (0.50 s each)"


def test_the_tuning_row_counts_the_most_trials_seen_running_at_once() -> None:
    t = timing_table(_records(), _trials()).set_index("phase")
    assert pd.isna(t.loc["tuning", "count"])  # runs recorded before it was counted
    records = _records()
    records[2] = {**records[2], "slots": 4, "running": 3}
    records[8] = {**records[8], "running": 1}
    t = timing_table(records, _trials())
    assert t.set_index("phase").loc["tuning", "count"] == 3
    assert any("4 slots" not in line and "(most running: 3)" in line for line in timing_lines(t))
