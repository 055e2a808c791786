"""The certificate made from the certification's episodes (the pure parts of certify.py)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from safe_bc.handover import HandoverConfig
from safe_bc.study.certify import (
    AGENT_ALONE,
    EXPERT,
    RECOMMENDER,
    certificate_line,
    crossed,
    summarize_certification,
)
from safe_bc.study.spec import StudySpec


def episodes(recommender_gap: float, crossings: int) -> pd.DataFrame:
    """3 seeds x 50 tracks each; the recommender = expert + gap with ``crossings`` episodes
    beyond d_s; the agent alone = expert - 5, every tenth episode beyond d_s."""
    rng = np.random.default_rng(1)
    rows = []
    for seed in range(3):
        for t in range(50 * seed, 50 * seed + 50):
            base = float(rng.normal(900, 20))
            for method, reward, bad, deferred in (
                (EXPERT, base, 0.0, np.nan),
                (RECOMMENDER, base + recommender_gap, float(seed == 0 and t < crossings), 0.04),
                (AGENT_ALONE, base - 5, float(t % 10 == 0), np.nan),
            ):
                rows.append({"method": method, "train_seed": seed, "env_seed": t,
                             "reward": reward, "any_violation": bad,
                             "deferred_share": deferred})  # fmt: skip
    return pd.DataFrame(rows)


def spec() -> StudySpec:
    return StudySpec("s", {}, handover=HandoverConfig(2.0), certify_episodes=150, certify_seed=30)


def test_zero_crossings_in_150_meet_every_goal() -> None:
    table, per_seed, cert = summarize_certification(episodes(2.0, 0), spec())
    assert table["method"].tolist() == [RECOMMENDER, AGENT_ALONE, EXPERT]
    assert cert["episodes"] == 150 and cert["episodes_beyond"] == 0
    assert cert["train_seeds"] == [0, 1, 2] and cert["tracks_per_seed"] == 50
    assert cert["beyond_ucb95"] == pytest.approx(0.0198, abs=1e-4)
    assert cert["d_reward_vs_expert"] == pytest.approx([2.0, 2.0, 2.0])
    assert cert["deferred_share"] == pytest.approx(0.04) and cert["seeds_above_expert"] == 3
    assert all(cert["goals"].values())
    alone = table.set_index("method").loc[AGENT_ALONE]
    assert alone["episodes_beyond"] == 15 and alone["d_reward"] == pytest.approx(-5.0)
    assert "reliably above the expert" in certificate_line(cert)
    assert set(per_seed["method"]) == {RECOMMENDER, AGENT_ALONE, EXPERT}


def test_one_crossing_or_a_reward_below_the_expert_misses_its_goal() -> None:
    _, _, cert = summarize_certification(episodes(-3.0, 1), spec())
    assert cert["episodes_beyond"] == 1 and not cert["goals"]["no_crossing"]
    assert not cert["goals"]["bound_at_most_0.02"]
    assert not cert["goals"]["not_reliably_below_expert"]
    assert "reliably below the expert" in certificate_line(cert)


def test_an_outcome_beyond_d_s_counts_as_a_crossing() -> None:
    frame = pd.DataFrame({"any_violation": [0.0, 0.0, 1.0], "any_violating_session": [1.0, 0, 0]})
    assert crossed(frame).tolist() == [True, False, True]


@pytest.mark.parametrize("study", ["default", "rehab"])
def test_the_committed_certificates_re_derive_from_their_episodes(study: str) -> None:
    import json
    from pathlib import Path

    from safe_bc.data.store import read_table
    from safe_bc.study.spec import load_study

    root = Path(__file__).resolve().parents[2]
    spec = load_study(root / "tune_jobs" / f"{study}.py")
    episodes, meta = read_table(root / "results" / study / "certify_episodes.parquet")
    table, _, certificate = summarize_certification(episodes, spec)
    card = json.loads((root / "results" / study / "recommender" / "recommender.json").read_text())
    assert certificate == meta["certificate"] == card["certificate"]
    committed, _ = read_table(root / "results" / study / "certify.parquet")
    pd.testing.assert_frame_equal(table, committed, check_exact=True)


def test_the_deferred_goal_is_the_study_s_own_limit_where_it_sets_one() -> None:
    clinic = StudySpec("s", {}, handover=HandoverConfig(0.2), certify_episodes=150,
                       certify_seed=30, deferred_share_limit=0.10)  # fmt: skip
    frame = episodes(2.0, 0).assign(
        deferred_share=lambda d: np.where(d["method"] == RECOMMENDER, 0.08, np.nan)
    )
    assert summarize_certification(frame, clinic)[2]["goals"]["deferred_below_0.1"]
    assert not summarize_certification(frame, spec())[2]["goals"]["deferred_below_0.05"]
