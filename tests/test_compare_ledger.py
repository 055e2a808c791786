"""The track-block ledger: which tracks every comparison of every family runs on. No two
tables share a track unless they share a runs folder or declare it (``shares_tracks_with``);
a fresh comparison never runs on its selection's tracks."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from safe_bc.compare.families import family, load_comparisons
from safe_bc.compare.protocol import Fresh, track_clashes
from safe_bc.compare.run import track_seeds
from safe_bc.compare.spec import Comparison

ROOT = Path(__file__).resolve().parents[1]
FAMILIES = sorted((ROOT / "tune_jobs/compare").glob("*.py"))


@pytest.fixture(scope="module")
def tables() -> dict[tuple[str, str], Comparison]:
    """Every comparison, resolved (fresh ones from their committed selection tables; planned
    ones, whose selection has not run, on their own tracks)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(ROOT)
        return {
            (f.stem, k): c for f in FAMILIES for k, c in load_comparisons(f, planned=True).items()
        }


def test_no_two_tables_share_tracks_undeclared(tables) -> None:
    # every table made, none planned
    assert len(tables) == 69
    assert track_clashes(tables.values(), track_seeds) == []


def test_the_ledger_fails_on_a_clash(tables) -> None:
    """A copy of a table under another name, on the same tracks, declaring nothing."""
    batch = tables[("observation", "batch")]
    clash = dataclasses.replace(batch, name="batch_again", shares_tracks_with=())
    found = track_clashes([*tables.values(), clash], track_seeds)
    assert len(found) == 6 and all("results/ablation/batch/batch_again " in x for x in found)
    assert any(x.startswith("results/ablation/batch/batch and ") for x in found)
    moved = dataclasses.replace(clash, eval_seed=99)
    assert track_clashes([*tables.values(), moved], track_seeds) == []


def test_fresh_tables_run_on_tracks_their_selection_did_not(tables) -> None:
    fresh = [
        (f.stem, k, e.follows)
        for f in FAMILIES
        for k, e in family(f).items()
        if isinstance(e, Fresh)
    ]
    assert len(fresh) == 26
    for stem, key, follows in fresh:
        ran = set(track_seeds(tables[(stem, key)]))
        chose = set(track_seeds(tables[(stem, follows)]))
        assert ran and not ran & chose, (stem, key)


def test_tables_sharing_a_runs_folder_define_their_shared_rows_alike(tables) -> None:
    """A runs folder holds one agent per (row, seed): tables that share it (declared in
    different families, e.g. the self-imitation comparison and the deferral designs) give a
    row of the same name the same definition, on the same task, demonstrations and BC."""
    groups: dict[tuple[str, str], list[Comparison]] = {}
    for c in tables.values():
        groups.setdefault((str(c.out), c.runs or c.name), []).append(c)
    shared = 0
    for group in groups.values():
        first = group[0]
        for c in group[1:]:
            assert (c.task, c.demos, c.bc) == (first.task, first.demos, first.bc), c.name
            for m in c.methods:
                if m.name in {r.name for r in first.methods}:
                    assert m == first.method(m.name), (first.name, c.name, m.name)
                    shared += 1
    assert shared > 50
