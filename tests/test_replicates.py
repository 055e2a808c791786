"""Replicate studies, the pure parts: distinct seed blocks, otherwise the same study; the table,
summary and verdict from synthetic final-phase frames."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import pandas as pd
import pytest

from safe_bc.seeds import heldout_seeds
from safe_bc.study.replicates import (
    REPLICATE_STRIDE,
    ReplicateResult,
    replicate_seeds,
    replicate_spec,
    replicate_table,
    replicates_markdown,
    replicates_summary,
)
from safe_bc.study.spec import load_study

REPO = Path(__file__).resolve().parents[1]
DEFAULT = load_study(REPO / "tune_jobs" / "default.py")
SEED_KEYS = {"name", "sampler_seed", "eval_seed", "final_seed", "certify_seed", "results",
             "storage", "optuna_storage", "base"}  # fmt: skip


def _training_seeds(spec) -> set[int]:
    first = spec.base.bc.train.seed
    return set(range(first, first + max(spec.train_seeds, spec.final_train_seeds)))


def test_replicates_use_disjoint_seed_blocks_and_are_otherwise_the_same_study() -> None:
    reps = [replicate_spec(DEFAULT, k) for k in range(4)]
    assert replicate_seeds(reps[0]) == replicate_seeds(DEFAULT)  # replicate 0: the study's seeds
    assert len({r.sampler_seed for r in reps}) == 4
    train = [_training_seeds(r) for r in reps]
    tracks = [
        set(heldout_seeds(r.eval_seed, r.eval_episodes))
        | set(heldout_seeds(r.final_seed, r.final_episodes + r.final_train_seeds))
        | set(heldout_seeds(r.certify_seed, r.certify_episodes))
        for r in reps
    ]
    for i in range(4):
        for j in range(i + 1, 4):
            assert not train[i] & train[j]
            assert not tracks[i] & tracks[j]
    base = {k: v for k, v in DEFAULT.summary().items() if k not in SEED_KEYS}
    for k, r in enumerate(reps):
        assert {k: v for k, v in r.summary().items() if k not in SEED_KEYS} == base
        # the base config differs in the training seed only
        assert r.base == replace(
            DEFAULT.base,
            bc=replace(DEFAULT.base.bc, train=replace(DEFAULT.base.bc.train, seed=k * 100)),
        )
        assert r.results == DEFAULT.results / "default" / "replicates"
        assert r.name == f"r{k}" and r.storage == "results/ray/default_replicates"
    assert REPLICATE_STRIDE == 100


def test_replicate_spec_refuses_overlapping_or_out_of_range_seeds() -> None:
    with pytest.raises(ValueError, match="multiple of 100"):
        replicate_spec(replace(DEFAULT, eval_seed=1, final_seed=101), 1)
    with pytest.raises(ValueError, match="eval_seed 1 and certify_seed 201 are a multiple of 100"):
        replicate_spec(replace(DEFAULT, certify_seed=201), 1)
    with pytest.raises(ValueError, match="training seeds"):
        replicate_spec(replace(DEFAULT, final_train_seeds=101), 0)
    with pytest.raises(ValueError, match="beyond the seed range"):
        replicate_spec(DEFAULT, 200)
    with pytest.raises(ValueError, match=">= 0"):
        replicate_spec(DEFAULT, -1)


Interval = tuple[float, float, float]


def _result(
    k: int, d: Interval, vs_bc: Interval, crossings: int, winner: str | None = "t1"
) -> ReplicateResult:
    """A replicate whose winner ``winner`` is ``d`` (value, lo, hi) from the expert and
    ``vs_bc`` from plain BC, with ``crossings`` of 51 episodes beyond d_s."""
    seeds = {"sampler_seed": 100 * k, "train_seed": 100 * k, "eval_seed": 1 + 100 * k,
             "final_seed": 2 + 100 * k}  # fmt: skip
    if winner is None:
        return ReplicateResult(k, seeds, None, False, {}, pd.DataFrame(), pd.DataFrame())
    final = pd.DataFrame(
        {
            "method": [winner, "t2", "plain_bc", "expert"],
            "reward": [900.0 + d[0], 880.0, 850.0, 900.0],
            "reward_lo": [890.0, 870.0, 700.0, 895.0],
            "reward_hi": [905.0, 890.0, 900.0, 905.0],
            "n_episodes": [51, 51, 51, 51],
            "episodes_with_violation": [crossings, 9, 1, 0],
            "violation_share_ucb": [0.1 + crossings / 100, 0.3, 0.09, 0.057],
        }
    )
    paired = pd.DataFrame(
        {
            "method": [winner, "t2", "plain_bc", winner, "t2"],
            "vs": ["expert", "expert", "expert", "plain_bc", "plain_bc"],
            "n_pairs": [51] * 5,
            "d_reward": [d[0], -20.0, -50.0, vs_bc[0], 30.0],
            "d_reward_lo": [d[1], -30.0, -200.0, vs_bc[1], 10.0],
            "d_reward_hi": [d[2], -10.0, -1.0, vs_bc[2], 50.0],
        }
    )
    params = {"selection.alpha": 0.25 * k, "bc.network.channels": "16-32-32"}
    return ReplicateResult(k, seeds, winner, True, params, final, paired)


PARAMS = ("selection.alpha", "bc.network.channels")


def test_table_rows_come_from_the_winners_final_phase_rows() -> None:
    table = replicate_table(
        [_result(1, (-0.3, -1.2, 0.2), (5.0, -1.0, 9.0), 1, winner="w9"),
         _result(0, (-2.3, -5.1, -1.2), (100.0, 2.0, 300.0), 2)],
        PARAMS,
    )  # fmt: skip
    assert table["replicate"].tolist() == [0, 1]  # replicate order
    first = table.iloc[0]
    assert first["winner"] == "t1" and first["reward"] == pytest.approx(897.7)
    assert (first["d_expert"], first["d_expert_lo"], first["d_expert_hi"]) == (-2.3, -5.1, -1.2)
    assert first["vs_expert"] == "below" and first["vs_plain_bc"] == "above"
    assert first["crossings"] == 2 and first["n_episodes"] == 51 and first["n_pairs"] == 51
    assert first["crossings_ucb"] == pytest.approx(0.12)
    assert first["expert_reward"] == 900.0 and first["plain_bc_reward"] == 850.0
    assert first["selection.alpha"] == "0.0" and first["final_seed"] == 2
    second = table.iloc[1]
    assert second["winner"] == "w9" and second["vs_expert"] == "spans zero"
    assert second["vs_plain_bc"] == "spans zero" and second["selection.alpha"] == "0.25"


def test_summary_says_reliably_below_when_every_interval_is_below_zero() -> None:
    table = replicate_table(
        [_result(k, (-2.0 - k, -4.0 - k, -0.5), (0.0, -1.0, 1.0), k) for k in range(3)], PARAMS
    )
    s = replicates_summary(table)
    assert (s["expert_below"], s["expert_above"], s["expert_spans_zero"]) == (3, 0, 0)
    assert s["d_expert_mean"] == pytest.approx(-3.0)
    assert (s["d_expert_min"], s["d_expert_max"]) == (-4.0, -2.0)
    assert s["crossings_total"] == 3 and s["episodes_total"] == 153
    assert s["distinct_configurations"] == 3  # alpha 0, 0.25, 0.5
    assert s["verdict"].startswith("the winner is reliably below the expert in all 3 replicates")
    assert "not reliably different from plain BC in any of the 3 replicates" in s["verdict"]
    assert "3 of 153 final-phase episodes beyond d_s" in s["verdict"]


def test_summary_says_no_reliable_effect_when_every_interval_spans_zero() -> None:
    table = replicate_table(
        [_result(k, (0.5, -1.0, 2.0), (10.0, 1.0, 20.0), 0) for k in range(2)], PARAMS
    )
    s = replicates_summary(table)
    assert s["expert_spans_zero"] == 2 and s["plain_bc_above"] == 2
    assert s["verdict"].startswith(
        "the winner is not reliably different from the expert in any of the 2 replicates "
        "(every interval spans zero: no reliable effect)"
    )
    assert "reliably above plain BC in all 2 replicates" in s["verdict"]


def test_mixed_replicates_give_a_mixed_verdict_and_a_missing_one_is_counted() -> None:
    table = replicate_table(
        [
            _result(0, (-2.3, -5.1, -1.2), (0.0, -1.0, 1.0), 2),
            _result(1, (-0.3, -1.2, 0.2), (0.0, -1.0, 1.0), 1),
            _result(2, (1.0, 0.2, 2.0), (0.0, -1.0, 1.0), 0),
            _result(3, (math.nan,) * 3, (math.nan,) * 3, 0, winner=None),
        ],
        PARAMS,
    )
    s = replicates_summary(table)
    assert (s["expert_below"], s["expert_spans_zero"], s["expert_above"]) == (1, 1, 1)
    assert s["expert_missing"] == 1 and s["with_winner"] == 3 and s["winner_feasible"] == 3
    assert "no consistent direction against the expert" in s["verdict"]
    assert "reliably below in 1, reliably above in 1" in s["verdict"]
    assert "of 3 replicates" in s["verdict"]
    assert table.iloc[3]["winner"] == "" and table.iloc[3]["vs_expert"] == "missing"
    assert s["distinct_configurations"] == 3  # the replicate without winner does not count
    text = replicates_markdown(table, s, PARAMS, note="Made by `x`.")
    assert "-2.3 [-5.1, -1.2]" in text and "2/51" in text and s["verdict"] in text
    assert "alpha=0.25" in text and text.rstrip().endswith("Made by `x`.")


def test_below_and_spanning_replicates_say_not_above() -> None:
    table = replicate_table(
        [_result(0, (-2.3, -5.1, -1.2), (0.0, -1.0, 1.0), 2),
         _result(1, (-0.3, -1.2, 0.2), (0.0, -1.0, 1.0), 1)],
        PARAMS,
    )  # fmt: skip
    verdict = replicates_summary(table)["verdict"]
    assert verdict.startswith(
        "the winner is not above the expert: reliably below in 1, no reliable effect (interval "
        "spans zero) in 1 of 2 replicates (reward difference mean -1.3, range -2.3 to -0.3)"
    )


def _certified(k: int, beyond: int, d: Interval) -> ReplicateResult:
    cert = {"method": "recommender", "episodes": 150, "episodes_beyond": beyond,
            "beyond_ucb95": 0.02 + beyond / 100, "deferred_share": 0.04 + k / 100,
            "reward": 905.0, "d_reward_vs_expert": list(d)}  # fmt: skip
    result = _result(k, (-1.0, -3.0, 1.0), (0.0, -1.0, 1.0), 1)
    seeds = {**result.seeds, "certify_seed": 30 + 100 * k}
    return replace(result, seeds=seeds, certificate=cert)


def test_certified_replicates_add_their_certificate_to_row_summary_verdict_and_report() -> None:
    table = replicate_table(
        [_certified(0, 0, (0.2, -0.8, 1.4)), _certified(1, 2, (-3.0, -5.0, -1.0))], PARAMS
    )
    first = table.iloc[0]
    assert first["certify_seed"] == 30 and first["cert_method"] == "recommender"
    assert (first["cert_beyond"], first["cert_episodes"]) == (0, 150)
    assert first["cert_vs_expert"] == "spans zero" and table.iloc[1]["cert_vs_expert"] == "below"
    s = replicates_summary(table)
    assert (s["certified"], s["cert_beyond_total"], s["cert_episodes_total"]) == (2, 2, 300)
    assert s["cert_deferred_max"] == pytest.approx(0.05)
    assert (s["cert_expert_below"], s["cert_expert_spans_zero"]) == (1, 1)
    assert "certified: 2 of 300 certification episodes beyond d_s over 2 replicates" in s["verdict"]
    assert "at most 5.0% of steps deferred" in s["verdict"]
    text = replicates_markdown(table, s, PARAMS)
    assert "certified on its own block" in text and "0/150" in text and "4.0%" in text
    assert "+0.2 [-0.8, +1.4]" in text


def test_uncertified_replicates_keep_the_table_without_certificate_columns() -> None:
    table = replicate_table([_result(0, (0.5, -1.0, 2.0), (0.0, -1.0, 1.0), 0)], PARAMS)
    assert "cert_method" not in table and "certify_seed" not in table
    s = replicates_summary(table)
    assert "certified" not in s and "certified" not in s["verdict"]
    assert "certified on its own block" not in replicates_markdown(table, s, PARAMS)


def test_a_replicate_finished_before_a_field_was_added_counts_as_finished(tmp_path) -> None:
    import json as _json

    from safe_bc.data.store import write_table_atomic
    from safe_bc.study.run_replicates import finished, replicate_inputs

    spec = replicate_spec(replace(DEFAULT, results=tmp_path), 1)
    folder = spec.results / spec.name
    folder.mkdir(parents=True)
    study = _json.loads(_json.dumps(spec.summary(), default=str))
    study.pop("validation_demos")  # recorded before the field existed
    write_table_atomic(folder / "final.parquet", pd.DataFrame({"a": [1]}),
                       {"complete": True, "study": study})  # fmt: skip
    assert not finished(spec)  # best.json is written last
    (folder / "best.json").write_text("{}")
    assert finished(spec)
    assert not finished(replace(spec, final_episodes=spec.final_episodes + 1))
    sources = {"r0": {"inputs": {"demos": {"digest": "sha256:a", "episodes": 5}}},
               "r1": {"inputs": {"demos": {"digest": "sha256:a", "episodes": 5}}},
               "r2": {}}  # fmt: skip
    assert replicate_inputs(sources) == {
        "demos": [{"digest": "sha256:a", "episodes": 5}, {"digest": None}]
    }
