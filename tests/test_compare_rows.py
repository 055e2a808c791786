"""Comparison rows: a closed set of kinds, each making its own stamp, policy and record; the
stamps name every committed stored evaluation and the records are the flat records
comparisons have always recorded."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from safe_bc.compare.families import family, load_comparison, load_comparisons
from safe_bc.compare.rows import FLAT_FIELDS, FLAT_METHODS, KINDS
from safe_bc.compare.spec import Agent, Comparison, Expert, FromStart, Handover, Method, View
from safe_bc.handover import HandoverConfig
from safe_bc.methods import METHODS
from safe_bc.methods.improve.config import ImproveConfig
from safe_bc.methods.queries.config import QueryConfig
from safe_bc.methods.selfimprove.config import SelfImproveConfig
from safe_bc.selection import SelectionConfig

ROOT = Path(__file__).parents[1]
FILES = sorted((ROOT / "tune_jobs/compare").glob("*.py"))
NAMES = [(f, name) for f in FILES for name in family(f)]
"""Every comparison of every family file: (file, address)."""


def test_every_stored_evaluation_keeps_its_stamp(monkeypatch) -> None:
    """Every committed stored evaluation (``OUT/stored_evaluations/<key>.parquet``) is the one the
    runner finds for some comparison cell now: the key of the stamp it computes for that cell
    (with the thresholds of the set it was made from) names the file, and the file records
    that stamp; stored evaluations stay reused."""
    from safe_bc.compare.eval_store import FOLDER, episodes_path
    from safe_bc.compare.run import cell_stamp
    from safe_bc.data.store import read_table_metadata

    monkeypatch.chdir(ROOT)
    committed = {
        p.resolve(): read_table_metadata(p)["stamp"]
        for p in Path("results").rglob(f"{FOLDER}/*.parquet")
        if not p.name.endswith(".steps.parquet")
    }
    limits = {str(s["thresholds"]): s["thresholds"] for s in committed.values()}  # each set's
    found: set[Path] = set()
    checked = 0
    cells = 0
    for file in FILES:
        for name, c in load_comparisons(file, planned=True).items():
            for m in c.methods:
                for s in c.seeds_of(m):
                    cells += 1
                    for thresholds in limits.values():
                        stamp = cell_stamp(c, m, s, thresholds)
                        path = episodes_path(c.out, stamp).resolve()
                        if path in committed:
                            assert committed[path] == stamp, (name, m.name, s)
                            found.add(path)
                            checked += 1
    assert cells == 588 + 103 + 60 + 132 + 72 + 42 + 33 + 33 + 10 + 36  # every cell: the made
    # ones (the queries family's 103, the clinic's self-imitation beyond_* 60, its Lagrangian
    # designs' 132, the car's beyond_* 72, the clinic's fifth beyond design's 42, the car's
    # second beyond design's 33, its third's 33, that design's deferral diagnostic's 10 and
    # its fourth's 36)
    assert checked >= 100  # the committed evaluations of every kind of row, some shared
    assert sorted(set(committed) - found) == []  # none left where no comparison looks


def test_runs_folder_sharers_share_an_evaluation_only_when_the_same_one() -> None:
    """Two comparisons sharing a runs folder: the same settings give every cell the same
    stored evaluation, other settings (here the tracks, or one row's alpha) other ones."""
    from safe_bc.compare.eval_store import episodes_path
    from safe_bc.compare.run import plan_evaluations

    a = Comparison(
        "a",
        methods=(
            Expert("expert"),
            Agent("bc", SelectionConfig(alpha=0.5)),
            Handover("bc+d2", "bc", HandoverConfig(2.0)),
        ),
        runs="shared",
        train_seeds=(0, 1),
        episodes=4,
    )
    limits = {a.demos: [10.0, 10.0, 10.0]}

    def files(c: Comparison) -> dict[str, Path]:
        return {
            k: episodes_path(c.out, cell.stamp) for k, cell in plan_evaluations(c, limits).items()
        }

    mine = files(a)
    assert len(set(mine.values())) == len(mine) == 5  # expert, 2 x bc, 2 x bc+d2
    assert files(dataclasses.replace(a, name="b")) == mine
    others = files(dataclasses.replace(a, name="b", episodes=5))
    assert set(others.values()).isdisjoint(mine.values())
    alpha = dataclasses.replace(
        a, name="b", methods=(a.methods[0], Agent("bc", SelectionConfig(alpha=0.3)), a.methods[2])
    )
    changed = files(alpha)
    assert changed["expert"] == mine["expert"]
    assert {k for k in mine if changed[k] != mine[k]} == {
        f"{r} seed={s}" for r in ("bc", "bc+d2") for s in (0, 1)
    }


@pytest.mark.parametrize(("file", "name"), NAMES, ids=[f"{f.stem}:{n}" for f, n in NAMES])
def test_every_row_records_its_flat_record(file: Path, name: str, monkeypatch) -> None:
    """Each row is one of the kinds; its record lists every flat field in order, and its flat
    spelling builds the same row back."""
    monkeypatch.chdir(ROOT)
    c = load_comparison(file, name, planned=True)
    for m in c.methods:
        assert isinstance(m, KINDS)
        flat = m.record()
        assert list(flat)[: len(FLAT_FIELDS)] == list(FLAT_FIELDS)
        if "method" in flat:  # a method with no flat field of its own (queries): no flat spelling
            assert isinstance(m, FromStart) and flat["method"] == m.method
            continue
        if "handover" in flat:  # per-dimension widths or a cap: no flat spelling either
            assert isinstance(m, Handover) and flat["handover"] == m.handover.to_dict()
            continue
        again = Method(**m.spelling())
        assert again == m and type(again) is type(m)
    assert [d["name"] for d in c.to_dict()["methods"]] == [m.name for m in c.methods]


def test_the_flat_spelling_gives_each_kind() -> None:
    sel = SelectionConfig(alpha=0.5)
    assert Method("a", selection=sel, seeds=(1,)) == Agent("a", sel, seeds=(1,))
    assert Method("e", expert=True) == Expert("e")
    assert Method("i", improve=ImproveConfig(), start="a") == FromStart("i", "a", ImproveConfig())
    si = Method("s", selfimprove=SelfImproveConfig(), start="a")
    assert si == FromStart("s", "a", SelfImproveConfig()) and si.kind == "selfimprove"
    assert Method("f", fallback_of="a") == Handover("f", "a")
    held = Method("d", fallback_of="a", defer_width=2.0, defer_hold=3, defer_hold_on=("front",))
    assert held == Handover("d", "a", HandoverConfig(2.0, hold=3, hold_on=("front",)))
    assert held.spelling() == {
        "name": "d", "fallback_of": "a", "label": "", "renderer": None, "defer_width": 2.0,
        "defer_hold": 3, "defer_lookahead": 0, "defer_hold_on": ("front",),
    }  # fmt: skip
    assert Method("m", masked_of="a") == View("m", "a", masked=True)
    assert Method("v", agents_of="a", renderer="exact") == View("v", "a", renderer="exact")
    for row in (held, si):  # a row has only its own kind's fields: no flat view of the others
        for field in ("selection", "expert", "agents_of", "defer_width", "fallback_of"):
            assert not hasattr(row, field)
    assert held.record()["selection"] is None and held.record()["defer_width"] == 2.0


def test_the_registry_gives_the_flat_record_its_method_fields() -> None:
    """The methods with a field of their own in the flat record are the registry's
    ``flat_field`` ones, and their fields stand where comparisons were first recorded with
    them; a registered method without one is refused by the flat spelling, with its row's
    spelling."""
    assert tuple(n for n, s in METHODS.items() if s.flat_field) == FLAT_METHODS
    assert FLAT_METHODS == ("improve", "selfimprove")
    assert list(FLAT_FIELDS) == [
        "name", "selection", "bc", "expert", "expert_config", "improve", "selfimprove", "start",
        "fallback_of", "defer_width", "defer_hold", "defer_lookahead", "defer_hold_on", "seeds",
        "masked_of", "label", "agents_of", "renderer", "demos",
    ]  # fmt: skip
    assert FLAT_FIELDS["improve"] is None and FLAT_FIELDS["selfimprove"] is None
    with pytest.raises(TypeError, match=r"'queries' \(a queries row: FromStart\('q', start='a'"):
        Method("q", queries=QueryConfig(), start="a")
    with pytest.raises(TypeError, match="unexpected keyword argument 'nope'"):
        Method("q", nope=1)


def test_a_method_row_names_a_registered_method() -> None:
    with pytest.raises(
        ValueError, match="no registered method takes a config of type SelectionConfig"
    ):
        FromStart("x", "a", SelectionConfig())
    with pytest.raises(ValueError, match="unknown method 'nope'"):
        FromStart("x", "a", ImproveConfig(), method="nope")
    with pytest.raises(ValueError, match="takes a config of type ImproveConfig"):
        FromStart("x", "a", SelfImproveConfig(), method="improve")
    with pytest.raises(ValueError, match="a row is one of"):
        Comparison("t", methods=(Agent("a", SelectionConfig()), "b"))  # type: ignore[arg-type]
    row = dataclasses.replace(Handover("d", "a", HandoverConfig(1.0)), of="b")
    assert row.record()["fallback_of"] == "b"


def test_comparisons_re_derive_their_tables_from_the_stored_evaluations(monkeypatch) -> None:
    """Every comparison whose cells' evaluations are committed re-derives its episode table
    value for value from them (found by key, in plan order, labelled as the runner labels
    them), and its table from that (with its committed training and history tables)."""
    import pandas as pd

    from safe_bc.compare.eval_store import FOLDER, episodes_path
    from safe_bc.compare.run import Cell, cell_stamp, episodes_table
    from safe_bc.compare.spec import build_table
    from safe_bc.data.store import read_table

    monkeypatch.chdir(ROOT)
    committed = {p.resolve(): p for p in Path("results").rglob(f"{FOLDER}/*.parquet")}
    limits = {
        str(t): t for t in (read_table(p)[1]["stamp"]["thresholds"] for p in committed.values())
    }
    derived = 0
    for _, c in (pair for f in FILES for pair in load_comparisons(f, planned=True).items()):
        plan, stored = {}, {}
        for m in c.methods:
            for s in c.seeds_of(m):
                key = m.policy_key(s)
                for t in limits.values():
                    stamp = cell_stamp(c, m, s, t)
                    path = episodes_path(c.out, stamp).resolve()
                    if path in committed:
                        plan[key], stored[key] = Cell(m, s, stamp), read_table(path)[0]
                        break
        if not plan or not (c.out / f"{c.name}_episodes.parquet").exists():
            continue  # (a planned comparison sharing some stored evaluations has no table yet)
        n_cells = sum(len(c.seeds_of(m)) for m in c.methods)
        assert len(plan) == n_cells, (c.name, "cells without a stored evaluation")
        episodes = episodes_table(plan, stored)
        pd.testing.assert_frame_equal(
            episodes, read_table(c.out / f"{c.name}_episodes.parquet")[0], check_exact=True
        )
        training = read_table(c.out / f"{c.name}_training.parquet")[0]
        history_file = c.out / f"{c.name}_history.parquet"
        history = read_table(history_file)[0] if history_file.exists() else None
        table = build_table(c, episodes, training, history)
        pd.testing.assert_frame_equal(
            table, read_table(c.out / f"{c.name}.parquet")[0], check_exact=True
        )
        derived += 1
    assert derived >= 7


def test_the_runner_asks_no_row_its_kind() -> None:
    """``safe_bc/compare/run.py`` calls the row interface (:class:`safe_bc.compare.rows.Row`):
    no ``isinstance`` or ``type(...) is`` test names a kind of row."""
    import ast

    source = (ROOT / "safe_bc/compare/run.py").read_text()
    kinds = {k.__name__ for k in KINDS}
    named = [
        ast.unparse(node)
        for node in ast.walk(ast.parse(source))
        if isinstance(node, ast.Call)
        and isinstance(node.func, ast.Name)
        and node.func.id in ("isinstance", "type")
        and kinds & {n.id for n in ast.walk(node) if isinstance(n, ast.Name)}
    ]
    assert named == []
