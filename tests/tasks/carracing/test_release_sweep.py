"""The drift release sweep: its committed table's Markdown re-derives from the committed
parquet, the committed sweep file is the committed run's settings, a row's figures on a
synthetic episode, and (slow) the default's row re-collected to the committed digits."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from safe_bc.data.episode import Episode
from safe_bc.data.store import read_table
from safe_bc.rollout.release_sweep import (
    DEFAULT_FILE,
    ReleaseSweep,
    collect_release,
    load_sweep,
    release_row,
    render_markdown,
    run_sweep,
)
from safe_bc.tasks.carracing.perturb import PerturbationConfig

ROOT = Path(__file__).resolve().parents[3]
COMMITTED = ROOT / "results/demos/release_sweep"


def test_committed_markdown_rederives_from_the_committed_table() -> None:
    table, meta = read_table(COMMITTED.with_suffix(".parquet"))
    assert render_markdown(table, meta) == COMMITTED.with_suffix(".md").read_text()


def test_sweep_file_is_the_committed_run() -> None:
    sweep = load_sweep(ROOT / DEFAULT_FILE)
    table, meta = read_table(COMMITTED.with_suffix(".parquet"))
    assert list(sweep.releases) == meta["releases"] == table["release_distance"].tolist()
    assert sweep.episodes == meta["episodes"] and (table["episodes"] == sweep.episodes).all()
    assert sweep.out == Path("results/demos")
    assert PerturbationConfig().release_distance in sweep.releases  # the default is a row


@pytest.mark.parametrize(
    ("kwargs", "match"), [({"releases": ()}, "releases"), ({"releases": (-1.0,)}, "releases"),
                          ({"episodes": 0}, "episodes")],
)  # fmt: skip
def test_sweep_validation(kwargs, match) -> None:
    with pytest.raises(ValueError, match=match):
        ReleaseSweep(**kwargs)


def _episode(safety: list, warmup: list, offroad: list, rewards: list) -> Episode:
    n = len(safety)
    return Episode(
        episode_id=0,
        seed=0,
        observations=np.zeros((n, 1), np.float32),
        actions=np.zeros((n, 3), np.float32),
        executed_actions=np.zeros((n, 3), np.float32),
        rewards=np.asarray(rewards, np.float32),
        terminated=np.zeros(n, bool),
        truncated=np.zeros(n, bool),
        safety=np.asarray(safety, np.float32),
        costs=np.zeros((n, 3), np.float32),
        warmup=np.asarray(warmup),
        offroad=np.asarray(offroad),
    )


def test_release_row_skips_warmup_and_takes_the_closest_per_dimension() -> None:
    a = _episode([[0.0, 0.0, 0.0], [4.0, 9.0, 2.0]], [True, False], [False, False], [1.0, 2.0])
    b = _episode([[3.0, 8.0, 5.0], [6.0, 7.0, 1.5]], [False, False], [False, True], [4.0, 5.0])
    row = release_row(6.0, [a, b], wheels=[4, 3, 4, 0])
    assert row == {
        "release_distance": 6.0,
        "episodes": 2,
        "closest_left": 3.0,
        "closest_front": 7.0,
        "closest_right": 1.5,
        "fewest_wheels_on_road": 0,
        "offroad_frames": 1,
        "reward_mean": 6.0,
    }


def test_default_release_row_recollects_to_the_committed_digits() -> None:
    """The committed row of the default release distance (6 px): its 5 default
    demonstration episodes collected again through :func:`collect_release` (~12 s)."""
    table, _ = read_table(COMMITTED.with_suffix(".parquet"))
    release = PerturbationConfig().release_distance
    committed = table[table["release_distance"] == release].reset_index(drop=True)
    renderer = load_sweep(ROOT / DEFAULT_FILE).renderer  # the committed table's
    again = pd.DataFrame([release_row(release, *collect_release(release, 5, renderer))])
    pd.testing.assert_frame_equal(again, committed, check_exact=True)


@pytest.mark.slow
def test_committed_table_recollects_exactly(tmp_path: Path) -> None:
    """The whole committed table through :func:`run_sweep` with the committed sweep file's
    settings (25 episodes, ~1 min), and its Markdown but for the provenance line."""
    table, _ = read_table(COMMITTED.with_suffix(".parquet"))
    sweep = replace(load_sweep(ROOT / DEFAULT_FILE), out=tmp_path)
    again = run_sweep(sweep, progress=False)
    pd.testing.assert_frame_equal(again, table, check_exact=True)
    written, _ = read_table(tmp_path / "release_sweep.parquet")
    pd.testing.assert_frame_equal(written, table, check_exact=True)
    head = COMMITTED.with_suffix(".md").read_text().split("\n\n")[0]
    assert (tmp_path / "release_sweep.md").read_text().split("\n\n")[0] == head


def test_the_script_loads_the_sweep_file(monkeypatch) -> None:
    """``python -m scripts.release_sweep FILE`` reads the file's SWEEP and runs it."""
    import scripts.release_sweep as script

    seen = []
    monkeypatch.setattr(script, "run_sweep", seen.append)
    assert script.main([str(ROOT / DEFAULT_FILE)]) == 0
    assert seen == [load_sweep(ROOT / DEFAULT_FILE)]
