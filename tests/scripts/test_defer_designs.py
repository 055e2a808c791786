"""The deferral designs' summary: the committed ``defer_designs.md`` re-derives from the
committed fresh-track tables, and the goal column follows the deferral goal
(``scripts.defer_designs.GOAL_BOUND``, ``GOAL_BURDEN``)."""

from __future__ import annotations

import pandas as pd

from scripts.defer_designs import FOLDER, markdown, meets_goal, summary


def test_committed_summary_rederives() -> None:
    table = summary()
    assert set(table["table"]) >= {"defer", "defer_trend"}
    assert markdown(table, "python -m scripts.defer_designs") == (
        (FOLDER / "defer_designs.md").read_text()
    )


def test_the_goal_needs_both_the_bound_and_the_burden() -> None:
    t = pd.DataFrame(
        {
            "95% bound": [0.0198, 0.0198, 0.031, 0.0198],
            "steps deferred": [0.049, 0.171, 0.01, float("nan")],
        }
    )
    assert meets_goal(t).tolist() == [True, False, False, False]
