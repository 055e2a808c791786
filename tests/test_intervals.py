"""One interval per comparison: the same episodes give the same crossed interval in any table."""

from __future__ import annotations

import numpy as np
import pandas as pd

from safe_bc.metrics import paired_crossed, summarize_crossed


def _episodes() -> pd.DataFrame:
    rng = np.random.default_rng(1)
    rows = []
    for method, shift in (("start", 0.0), ("both", 20.0), ("ppo", -300.0), ("extra", 5.0)):
        for s in range(3):
            for t in range(12):
                reward = 600 + shift + 40 * np.sin(t) + rng.normal(0, 30)
                rows.append({"method": method, "train_seed": s, "env_seed": 100 + t,
                             "reward": reward})  # fmt: skip
    return pd.DataFrame(rows)


def test_an_interval_does_not_depend_on_the_other_rows_of_its_table() -> None:
    ep = _episodes()
    small = ep[ep["method"].isin(["start", "both"])]
    a = paired_crossed(ep, "start", ["reward"]).set_index("method").loc["both"]
    b = paired_crossed(small, "start", ["reward"]).set_index("method").loc["both"]
    assert (a["d_reward_lo"], a["d_reward_hi"]) == (b["d_reward_lo"], b["d_reward_hi"])
    s1 = summarize_crossed(ep, ["method"], ["reward"]).set_index("method").loc["both"]
    s2 = summarize_crossed(small, ["method"], ["reward"]).set_index("method").loc["both"]
    assert (s1["reward_lo"], s1["reward_hi"]) == (s2["reward_lo"], s2["reward_hi"])
    other = summarize_crossed(small, ["method"], ["reward"], seed=1).set_index("method")
    assert other.loc["both", "reward_lo"] != s1["reward_lo"]  # the bootstrap seed still counts
