"""The committed rerun report re-derives from the committed copies, and says yes for all."""

from __future__ import annotations

import pandas as pd

from scripts.study_rerun import OUT, comparable, difference, report


def test_the_committed_report_re_derives_and_every_table_is_equal() -> None:
    text = report()
    assert (OUT / "rerun.md").read_text() == text
    assert "| no " not in text and text.count("| yes ") == 6


def test_a_changed_value_is_a_difference() -> None:
    a = comparable(pd.DataFrame({"method": ["ab12cd34", "expert"], "reward": [1.0, 2.0]}), "x")
    b = a.assign(reward=[1.0, 2.5])
    assert a["method"].tolist() == ["<trial>", "expert"]
    assert difference(a, a) == "" and "reward" in difference(a, b)
