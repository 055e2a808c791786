"""The final phase's paired table (pure pieces of study/final.py)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from safe_bc.methods.experiment import RunConfig
from safe_bc.selection import SelectionConfig
from safe_bc.study.final import EXPERT, PLAIN_BC, final_paired, final_summaries


def episodes() -> pd.DataFrame:
    """2 seeds, each on its own 4 tracks; candidate "a" = expert - 2 on every track, plain BC =
    expert - 10 on seed 0 and the expert on seed 1."""
    rng = np.random.default_rng(0)
    rows = []
    for seed, tracks in ((0, range(4)), (1, range(4, 8))):
        for t in tracks:
            base = float(rng.normal(900, 30))
            for method, reward in (
                (EXPERT, base),
                ("a", base - 2),
                (PLAIN_BC, base - 10 * (seed == 0)),
            ):
                bad = float(method == "a" and t == 0)
                rows.append({"method": method, "train_seed": seed, "env_seed": t,
                             "reward": reward, "any_violation": bad})  # fmt: skip
    return pd.DataFrame(rows)


def test_every_method_against_the_expert_and_candidates_against_plain_bc() -> None:
    out = final_paired(episodes(), seed=2).set_index(["method", "vs"])
    assert set(out.index) == {("a", EXPERT), (PLAIN_BC, EXPERT), ("a", PLAIN_BC)}
    a = out.loc[("a", EXPERT)]
    assert (a["d_reward"], a["d_reward_lo"], a["d_reward_hi"]) == pytest.approx((-2, -2, -2))
    assert a["n_pairs"] == 8 and a["d_any_violation"] == pytest.approx(1 / 8)
    assert out.loc[("a", PLAIN_BC), "d_reward"] == pytest.approx(3.0)
    assert (
        out.loc[(PLAIN_BC, EXPERT), "d_reward_lo"]
        <= -5
        <= out.loc[(PLAIN_BC, EXPERT), "d_reward_hi"]
    )


def test_same_episodes_same_intervals() -> None:
    pd.testing.assert_frame_equal(final_paired(episodes(), 2), final_paired(episodes(), 2))


def test_a_rerun_with_other_trial_ids_gives_the_same_intervals() -> None:
    """Tune's trial ids are random per run; the final tables' intervals must not depend on
    them (the same candidates under other ids: same numbers, the ids in the rows)."""
    eps = episodes()
    eps["reward"] += np.random.default_rng(1).normal(0, 20, len(eps))  # intervals of width > 0
    cfgs = {"a": RunConfig(selection=SelectionConfig(eps=1.5)), PLAIN_BC: RunConfig()}
    table, paired = final_summaries(eps, cfgs, seed=2)
    renamed = eps.assign(method=eps["method"].replace({"a": "b"}))
    cfgs_b = {"b": cfgs["a"], PLAIN_BC: cfgs[PLAIN_BC]}
    table_b, paired_b = final_summaries(renamed, cfgs_b, seed=2)
    assert set(table["method"]) == {"a", EXPERT, PLAIN_BC}
    assert set(paired["method"]) == {"a", PLAIN_BC}
    pd.testing.assert_frame_equal(
        table.replace({"a": "b"}).sort_values("method").reset_index(drop=True),
        table_b.sort_values("method").reset_index(drop=True),
    )
    pd.testing.assert_frame_equal(paired.replace({"a": "b"}), paired_b)
    a = paired.set_index(["method", "vs"]).loc[("a", EXPERT)]
    assert a["d_reward_lo"] < a["d_reward"] < a["d_reward_hi"]
