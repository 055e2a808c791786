"""The self-imitation choice: the rule, and each committed ``choice.md`` re-derives from its
committed selection table."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from safe_bc.data.store import read_table
from scripts.selfimprove_choice import choice_path, choose, markdown

ROOT = Path(__file__).resolve().parents[2]
TABLES = sorted((ROOT / "results/selfimprove").glob("*/selection.parquet")) + sorted(
    (ROOT / "results/selfimprove").glob("*/rounds.parquet")
)


def test_the_rule_wants_a_reliable_gain_then_fewest_crossings_then_reward() -> None:
    t = pd.DataFrame(
        {"d_reward_lo": [0.1, 0.2, 0.3, -0.1], "b": [5, 3, 3, 0], "reward": [1.0, 2.0, 2.5, 9.0]},
        index=["defaults", "x", "y", "z"],
    )
    assert choose(t, "b", list(t.index))[0] == "y"  # z has no reliable gain; x ties on b
    assert choose(t, "b", ["defaults", "z"])[0] == "defaults"
    assert choose(t, "b", ["z"])[0] is None


@pytest.mark.parametrize("table", TABLES, ids=lambda p: f"{p.parent.name}-{p.stem}")
def test_committed_choice_rederives(table: Path) -> None:
    frame, meta = read_table(table)
    command = "python -m scripts.selfimprove_choice " + str(table.relative_to(ROOT))
    assert markdown(frame, meta, table.relative_to(ROOT), command) == (
        choice_path(table).read_text()
    )


def test_there_is_a_committed_table() -> None:
    assert TABLES
