"""The selection-then-fresh protocol: the rules, their resolution and the track ledger."""

from __future__ import annotations

import pandas as pd
import pytest

from safe_bc.compare.families import load_comparison
from safe_bc.compare.protocol import Fresh, Rule, resolve, track_clashes
from safe_bc.compare.spec import Agent, Comparison, Expert, Handover
from safe_bc.handover import HandoverConfig
from safe_bc.selection import SelectionConfig


def _selection(**changes) -> Comparison:
    rows = (
        Expert("expert"),
        Agent("a", SelectionConfig()),
        Agent("b", SelectionConfig(alpha=0.5)),
        *(Handover(f"{x}+{w:g}", x, HandoverConfig(w)) for x in ("a", "b") for w in (2.0, 1.0)),
    )
    return Comparison("sel", rows, eval_seed=17, **changes)


def _table(beyond: dict[str, int], share: dict[str, float] | None = None) -> pd.DataFrame:
    share = share or {}
    return pd.DataFrame(
        {
            "method": list(beyond),
            "episodes_with_violation": list(beyond.values()),
            "deferred_share": [share.get(m, 0.0) for m in beyond],
        }
    )


def test_smallest_safe_width_per_agent() -> None:
    fresh = Fresh("fresh", "sel", (Rule("smallest_safe_width"),), eval_seed=14)
    table = _table({"a+2": 0, "a+1": 1, "b+2": 2, "b+1": 3})
    c = resolve(fresh, _selection(), table)
    assert [m.name for m in c.methods] == ["expert", "a", "b", "a+2", "b+2"]
    assert (c.name, c.eval_seed, c.episodes) == ("fresh", 14, 20)
    table = _table({"a+2": 0, "a+1": 0, "b+2": 0, "b+1": 3})
    assert [m.name for m in resolve(fresh, _selection(), table).methods][3:] == ["a+1", "b+2"]


def test_smallest_safe_width_counts_the_column_it_is_given() -> None:
    """The clinic's rule counts outcomes beyond d_s (a ``total_`` column), not steps."""
    rule = Rule("smallest_safe_width", {"beyond": "total_any_violating_session"})
    table = _table({"a+2": 1, "a+1": 1, "b+2": 1, "b+1": 1}).assign(
        total_any_violating_session=[1, 0, 0, 2]
    )
    fresh = Fresh("fresh", "sel", (rule,), eval_seed=14)
    assert [m.name for m in resolve(fresh, _selection(), table).methods][3:] == ["a+1", "b+2"]
    plain = Fresh("fresh", "sel", (Rule("smallest_safe_width"),), eval_seed=14)
    assert [m.name for m in resolve(plain, _selection(), table).methods][3:] == ["a+2", "b+2"]


def test_least_deferred_falls_back_to_the_next_rule() -> None:
    strict = Rule("least_deferred", {"burden": 0.05})
    relaxed = Rule("least_deferred", {"burden": 1.0}, note=" (relaxed)")
    fresh = Fresh("f", "sel", (strict, relaxed), eval_seed=20, episodes=50, note="chosen{rule}.")
    beyond = {"a+2": 0, "a+1": 0, "b+2": 1, "b+1": 0}
    table = _table(beyond, {"a+2": 0.2, "a+1": 0.1, "b+2": 0.01, "b+1": 0.1})
    c = resolve(fresh, _selection(), table)
    assert [m.name for m in c.methods][3:] == ["a+1"]  # the tie goes to table order
    assert (c.note, c.episodes) == ("chosen (relaxed).", 50)
    table = _table(beyond, {"a+2": 0.2, "a+1": 0.04, "b+2": 0.01, "b+1": 0.1})
    assert resolve(fresh, _selection(), table).note == "chosen."
    none = Fresh("f", "sel", (strict,), eval_seed=20)
    c = resolve(none, _selection(), _table(beyond, dict.fromkeys(beyond, 1.0)))
    assert [m.name for m in c.methods] == ["expert", "a", "b"]


def test_best_lower_bound_takes_the_highest_paired_bound_among_safe_cheap_rows() -> None:
    rule = Rule("best_lower_bound", {"burden": 0.05})
    fresh = Fresh("f", "sel", (rule,), eval_seed=25)
    table = _table({"a+2": 0, "a+1": 0, "b+2": 1, "b+1": 0, "a": 0, "b": 0},
                   {"a+2": 0.03, "a+1": 0.06, "b+2": 0.01, "b+1": 0.04})  # fmt: skip
    table["d_reward_lo"] = [-1.0, 5.0, 9.0, 0.5, None, None]
    table["env_steps"] = [None, None, None, None, 200.0, 100.0]
    # a+1 defers too much, b+2 crossed: b+1 (0.5) beats a+2 (-1)
    assert [m.name for m in resolve(fresh, _selection(), table).methods][3:] == ["b+1"]
    table.loc[table["method"] == "a+2", "d_reward_lo"] = 0.5  # a tie: fewer env steps (b's)
    assert [m.name for m in resolve(fresh, _selection(), table).methods][3:] == ["b+1"]
    table.loc[table["method"] == "b", "env_steps"] = 300.0
    assert [m.name for m in resolve(fresh, _selection(), table).methods][3:] == ["a+2"]


def test_a_rule_is_named_and_the_table_has_the_candidates() -> None:
    with pytest.raises(ValueError, match="unknown rule 'best'"):
        Rule("best")
    fresh = Fresh("f", "sel", (Rule("smallest_safe_width"),), eval_seed=3)
    with pytest.raises(ValueError, match="lacks rows"):
        resolve(fresh, _selection(), _table({"a+2": 0}))


def test_a_fresh_comparison_reads_its_selection_table_when_loaded(tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "fam.py").write_text(
        "from safe_bc.compare.spec import Agent, Comparison, Handover\n"
        "from safe_bc.handover import HandoverConfig\n"
        "from safe_bc.compare.protocol import Fresh, Rule\n"
        "from safe_bc.selection import SelectionConfig\n"
        "COMPARISONS = (\n"
        "    Comparison('sel', (Agent('a', SelectionConfig()),\n"
        "        *(Handover(f'a+{w:g}', 'a', HandoverConfig(w)) for w in (1.0, 2.0))),\n"
        "        eval_seed=5),\n"
        "    Fresh('fresh', 'sel', (Rule('smallest_safe_width'),), eval_seed=6),\n"
        ")\n"
    )
    with pytest.raises(FileNotFoundError, match="--name sel first"):
        load_comparison(tmp_path / "fam.py", "fresh")
    (tmp_path / "results").mkdir()
    _table({"a": 0, "a+1": 1, "a+2": 0}).to_parquet(tmp_path / "results/sel.parquet")
    c = load_comparison(tmp_path / "fam.py", "fresh")
    assert [m.name for m in c.methods] == ["a", "a+2"] and c.eval_seed == 6
    with pytest.raises(ValueError, match=r"name one comparison \(--name\): sel, fresh"):
        load_comparison(tmp_path / "fam.py")
    with pytest.raises(ValueError, match="no comparison 'x'"):
        load_comparison(tmp_path / "fam.py", "x")


def test_the_ledger_finds_an_undeclared_clash() -> None:
    def blocks(c: Comparison) -> range:
        return range(c.eval_seed * 1000, c.eval_seed * 1000 + c.episodes)

    a = Comparison("a", (Expert("expert"),), eval_seed=3)
    b = Comparison("b", (Expert("expert"),), eval_seed=3, episodes=5)
    assert track_clashes([a, b], blocks) == [
        "results/a and results/b share 5 tracks (task carracing) undeclared"
    ]
    assert not track_clashes([a, Comparison("b", a.methods, eval_seed=4)], blocks)
    assert not track_clashes([a, Comparison("b", a.methods, eval_seed=3, runs="a")], blocks)
    declared = Comparison("b", a.methods, eval_seed=3, shares_tracks_with=("results/a",))
    assert not track_clashes([a, declared], blocks)
    assert not track_clashes([a, Comparison("b", a.methods, eval_seed=3, task="rehab")], blocks)
