"""The ``make tune`` floor: its arithmetic on the committed side-by-side
tables, and the precision timer's shape (no wall-clock is asserted)."""

from __future__ import annotations

import pytest

from scripts.tune_floor import floor, markdown, step_ms


def test_the_floor_adds_one_seed_trials_the_final_phase_and_the_fixed_costs() -> None:
    f = floor()
    assert f["trials"] >= 16 and f["final_trainings"] == 12
    assert f["trial_episodes"] == 8 * 3 + 8 * 10  # the screened half on 3 tracks, the rest 10
    tuning = (f["trials"] * f["training_s_cheapest"] + f["trial_episodes"] * f["episode_s"]) / 2
    assert f["floor_s"] == pytest.approx(tuning + f["final_phase_s"] + f["fixed_s"])
    assert f["training_s_cheapest"] <= f["training_s_mean"] and f["floor_s"] <= f["typical_s"]
    assert f["floor_ratio"] == pytest.approx(f["floor_s"] / f["old_wall_s"])
    assert "0.5x" in markdown(f, None)


def test_the_precision_timer_runs_one_step() -> None:
    assert step_ms((8, 16, 16), 64, 2, bf16=False, steps=1) > 0
