"""Long end-to-end checks (``make test-slow``): full-length episodes and the smoke study."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from safe_bc.cli.commands import main
from safe_bc.data.store import read_episodes, read_table
from safe_bc.distributed.collect import collect
from safe_bc.rollout.collect import CollectConfig
from tests.conftest import TINY_COLLECT

pytestmark = pytest.mark.slow
REPO = Path(__file__).resolve().parents[1]


def test_full_length_collection_is_deterministic_and_safe(ray_session, tmp_path: Path) -> None:
    """Two full default episodes, collected twice: identical, and never all wheels off."""
    a = collect(CollectConfig(episodes=2, workers=2), tmp_path / "a", progress=False)
    b = collect(CollectConfig(episodes=2, workers=1), tmp_path / "b", progress=False)
    assert a.collected == b.collected == [0, 1]
    for x, y in zip(read_episodes(tmp_path / "a"), read_episodes(tmp_path / "b"), strict=True):
        np.testing.assert_array_equal(x.observations, y.observations)
        np.testing.assert_array_equal(x.costs, y.costs)
        assert not x.offroad.any()
        assert x.total_reward > 600


def test_smoke_study_through_the_cli(ray_session, tiny_demos, tmp_path: Path) -> None:
    """`safe-bc tune tune_jobs/smoke.py` end to end: tables, winner, figure."""
    study = tmp_path / "smoke.py"  # the smoke study, expecting the tiny set's collection
    study.write_text(
        "from dataclasses import replace\n"
        "from safe_bc.rollout.collect import CollectConfig\n"
        "from safe_bc.study.spec import load_study\n"
        f"STUDY = replace(load_study({str(REPO / 'tune_jobs' / 'smoke.py')!r}), "
        f"collect={TINY_COLLECT})\n"
    )
    code = main(
        [
            "tune",
            str(study),
            "--storage",
            str(tmp_path / "ray"),
            "--demos",
            str(tiny_demos),
            "--trials",
            "3",
            "--results",
            str(tmp_path / "results"),
        ]
    )
    assert code == 0
    out = tmp_path / "results" / "smoke"
    trials, meta = read_table(out / "trials.parquet")
    assert len(trials) == 3 and meta["provenance"]["git_revision"]
    assert (out / "pareto.png").exists() and (out / "best.json").exists()
