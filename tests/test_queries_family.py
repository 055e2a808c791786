"""The queries family (``tune_jobs/compare/queries.py``) through the one comparison runner:
DAgger's budget from the critical-zone run, one-env episodes and the summary's layout (its
re-derivation from the committed outputs: ``tests/scripts/test_queries_report.py``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest

from safe_bc.compare.spec import Agent, Comparison, Expert, FromStart, Handover
from safe_bc.handover import HandoverConfig
from safe_bc.methods import Improved
from safe_bc.methods.queries.config import QueryConfig
from safe_bc.methods.queries.summary import block_episodes, queries_per_episode, widths_table
from safe_bc.selection import SelectionConfig


def _comparison(**changes) -> Comparison:
    q = QueryConfig(rounds=2, episodes_per_round=4)
    rows = (
        Expert("expert"),
        Agent("bc", SelectionConfig(alpha=0.5)),
        FromStart("critical", "bc", q),
        FromStart("full", "bc", dataclasses.replace(q, mode="full", budget_of="critical")),
        Handover("defer-2", "bc", HandoverConfig(2.0)),
    )
    return Comparison("q", rows, train_seeds=(0, 1), **changes)


def test_dagger_gets_the_critical_runs_queries_per_round() -> None:
    from safe_bc.compare.run import method_config, method_identity

    c = _comparison()
    full = c.method("full")
    improved = {("critical", 1): Improved(policy=None, net=None, report={"queries_total": 7.0})}
    resolved = method_config(c, full, 1, improved)
    assert (resolved.query_budget, resolved.budget_of, resolved.seed) == (4, "", 1)
    identity = method_identity(c, full, 1)  # names the run that fixes the budget
    assert identity["budget_of"] == method_identity(c, c.method("critical"), 1)
    assert identity["budget_of"]["seed"] == 1 and identity["query_budget"] is None
    assert "budget_of" not in QueryConfig().to_dict()  # other runs keep their records


def test_budget_of_names_an_earlier_run_of_the_method_from_the_same_start() -> None:
    c = _comparison()
    late = (*c.methods[:2], c.methods[3], c.methods[2])
    with pytest.raises(ValueError, match="budget_of 'critical' is no earlier queries row"):
        dataclasses.replace(c, methods=late)
    with pytest.raises(ValueError, match="query_budget or budget_of"):
        QueryConfig(query_budget=3, budget_of="critical")


def test_the_evaluation_runs_one_env_at_a_time_when_asked() -> None:
    from safe_bc.compare.run import cell_stamp, eval_config

    rows = _comparison(lockstep_forward="rows")
    assert eval_config(rows).lockstep_forward == "rows"
    assert eval_config(_comparison()).lockstep_forward == "batched"
    stamp = cell_stamp(rows, rows.method("bc"), 0, [1.0])
    assert "lockstep_forward" not in stamp["eval"]  # the one-env stamps
    assert "lockstep_forward" not in _comparison().to_dict()
    with pytest.raises(ValueError, match="lockstep_forward"):
        _comparison(lockstep_forward="fast")


def test_the_summary_lays_out_a_block_as_the_measurement_did() -> None:
    cells = [("expert", 0), *((m, s) for s in (0, 1) for m in ("defer-2", "defer-4", "bc"))]
    episodes = pd.DataFrame(
        [
            {"method": m, "train_seed": s, "env_seed": t, "violating_sessions": t % 2}
            for m, s in cells
            for t in (5, 6)
        ]
    )
    out = block_episodes(episodes, {"defer-4": "defer"}, 11)
    assert list(zip(out["method"], out["train_seed"], strict=True))[::2] == [
        ("expert", 0), ("bc", 0), ("defer", 0), ("bc", 1), ("defer", 1)
    ]  # fmt: skip
    assert (out["block"] == 11).all() and list(out["env_seed"][:2]) == [5, 6]
    tried = widths_table(
        episodes, [("defer-4", "bc", 4.0), ("defer-2", "bc", 2.0)], "violating_sessions"
    )
    assert tried.to_dict("records")[0] == {
        "agent": "bc", "width": 2.0, "episodes_beyond": 2, "episodes": 4
    }  # fmt: skip
    history = pd.DataFrame(
        {"method": ["critical"] * 2 + ["full"] * 2, "train_seed": [0, 1, 0, 1],
         "queries": [4, 2, 8, 8], "episodes": [16, 16, 16, 16]}
    )  # fmt: skip
    q = queries_per_episode(history)
    assert q["critical"] == q["critical+defer"] == pytest.approx(3 / 16)
    assert q["full"] == 0.5 and q["bc_safe"] == 0.0 and np.isnan(q["bc"])
