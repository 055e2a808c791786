"""safe_bc.report: an estimate gets an interval only from enough episodes."""

from __future__ import annotations

import pandas as pd
import pytest

from safe_bc.report import MIN_EPISODES_FOR_INTERVAL, estimate_lines

ROW = pd.Series(
    {"reward": 12.5, "reward_lo": 10.0, "reward_hi": 15.0, "safety_mean": 0.25}
    | {"safety_mean_lo": 0.125, "safety_mean_hi": 0.5}
)


@pytest.mark.parametrize("n", [1, 2, MIN_EPISODES_FOR_INTERVAL - 1])
def test_too_few_episodes_print_the_means_without_an_interval(n):
    lines = estimate_lines(ROW, ["reward", "safety_mean"], n)
    text = "\n".join(lines)
    assert "CI" not in text and "[" not in text
    assert "too few episodes for an interval" in lines[0] and f"means of {n} episode" in lines[0]
    assert lines[1:] == ["         reward:    12.500", "    safety_mean:     0.250"]


def test_enough_episodes_print_the_interval():
    lines = estimate_lines(ROW, ["reward", "safety_mean"], MIN_EPISODES_FOR_INTERVAL)
    assert lines == [
        "         reward:    12.500  95% CI [10.000, 15.000]",
        "    safety_mean:     0.250  95% CI [0.125, 0.500]",
    ]
    assert not any("too few" in line for line in lines)
