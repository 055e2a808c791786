"""The handover measurement's grid, table and rule (pure)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from safe_bc.compare.handover_choice import (
    EXPERT,
    HandoverChoice,
    candidate_label,
    choice_table,
    choose,
    handover_grid,
)
from safe_bc.handover import HandoverConfig


def _choice(candidates: tuple[HandoverConfig, ...], limit: float = 0.1) -> HandoverChoice:
    return HandoverChoice("t", Path("r"), candidates, 60, 4, limit, Path("o"))


def test_grid_covers_every_combination_and_fallback() -> None:
    grid = handover_grid({"a": (0.1, 0.2), "b": (0.3,)}, fallbacks=("expert", "cap"))
    assert len(grid) == 4
    assert {h.fallback for h in grid} == {"expert", "cap"}
    assert grid[1].widths == (("a", 0.2), ("b", 0.3)) and grid[1].width == 0.3


def _episodes(beyond: dict[str, list[int]], deferred: dict[str, float]) -> pd.DataFrame:
    rows = []
    for method, flags in beyond.items():
        seeds = [-1] if method == EXPERT else [0, 1]
        for s in seeds:
            for t, flag in enumerate(flags):
                rows.append({"method": method, "train_seed": s, "env_seed": t,
                             "reward": 10.0 + t + (0 if method == EXPERT else 1),
                             "any_violation": flag, "violation_steps": flag,
                             "deferred_share": deferred.get(method, np.nan)})  # fmt: skip
    return pd.DataFrame(rows)


def test_the_rule_takes_the_fewest_deferred_among_safe_rows_under_the_limit() -> None:
    grid = handover_grid({"a": (0.1, 0.2, 0.3)})
    c = _choice(grid)
    episodes = _episodes(
        {"h00": [0, 1, 0], "h01": [0, 0, 0], "h02": [0, 0, 0], EXPERT: [0, 0, 1]},
        {"h00": 0.01, "h01": 0.05, "h02": 0.08},
    )
    table = choice_table(episodes, c)
    assert table.set_index("candidate")["episodes_beyond"].to_dict() == {
        "h00": 2, "h01": 0, "h02": 0, EXPERT: 1,
    }  # fmt: skip
    assert table.set_index("candidate").loc["h01", "d_reward_vs_expert"] == 1.0
    assert choose(table, c) == 1
    assert candidate_label(choose(table, c)) == "h01"
    assert choose(table, _choice(grid, limit=0.04)) is None  # every safe row defers too much


def test_the_fallback_rule_takes_the_fewest_crossings_under_the_deferral_limit() -> None:
    from dataclasses import replace

    grid = handover_grid({"a": (0.1, 0.2, 0.3)})
    c = replace(_choice(grid), rule="fewest_deferred_else_fewest_beyond")
    episodes = _episodes(
        {"h00": [1, 1, 0], "h01": [0, 1, 0], "h02": [0, 0, 0], EXPERT: [0, 0, 1]},
        {"h00": 0.01, "h01": 0.05, "h02": 0.5},
    )
    table = choice_table(episodes, c)
    assert choose(table, _choice(grid)) is None  # the zero-crossing row defers too much
    assert choose(table, c) == 1  # fewest crossings (2 of 6) among rows under the limit


def test_the_clinic_s_handover_is_the_row_its_last_committed_measurement_chose() -> None:
    """``TaskSpec.handover`` of rehab is the handover ``tune_jobs/handover/rehab_safest.py``'s
    table chose (its metadata's ``chosen``), re-chosen from the committed table by its rule."""
    import runpy

    from safe_bc.data.store import read_table
    from safe_bc.tasks import task_defaults

    root = Path(__file__).resolve().parents[1]
    choice = runpy.run_path(str(root / "tune_jobs/handover/rehab_safest.py"))["CHOICE"]
    table, meta = read_table(root / choice.out / "choice.parquet")
    index = choose(table, choice)
    assert index is not None
    assert choice.candidates[index].to_dict() == meta["chosen"]
    assert task_defaults("rehab").handover == choice.candidates[index]


def test_the_cap_the_later_tables_name_is_the_one_stage_2_chose() -> None:
    """Stage 3 measures stage 2's chosen cap again and the self-imitation tables ran with it:
    both files spell it (experiment files read no results), and both spellings are the handover
    ``tune_jobs/handover/rehab_cap.py``'s committed table chose."""
    import runpy

    from safe_bc.data.store import read_table
    from safe_bc.handover import HandoverConfig

    root = Path(__file__).resolve().parents[1]
    stage2 = runpy.run_path(str(root / "tune_jobs/handover/rehab_cap.py"))["CHOICE"]
    chosen = HandoverConfig.from_dict(read_table(root / stage2.out / "choice.parquet")[1]["chosen"])
    stage3 = runpy.run_path(str(root / "tune_jobs/handover/rehab_safest.py"))
    selfimprove = runpy.run_path(str(root / "tune_jobs/compare/selfimprove.py"))
    assert stage3["CHOSEN_CAP"] == chosen == selfimprove["REHAB_HANDOVER"]
