"""scripts/eval_budget: variance components of a crossed episode table and predicted designs."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

import scripts.eval_budget as eval_budget
from safe_bc.data.store import read_table, write_table_atomic
from safe_bc.metrics import VarianceComponents


def _episodes(rng: np.random.Generator) -> pd.DataFrame:
    """Plain BC, a method whose gap to it varies by seed only, and an expert, on 6 tracks."""
    seeds, tracks = np.arange(5), 100 + np.arange(6)
    track_effect = rng.normal(0, 30, len(tracks))
    rows = []
    for s in seeds:
        seed_gap = rng.normal(-50, 40)
        for j, t in enumerate(tracks):
            base = 900 + track_effect[j] + rng.normal(0, 3)
            rows += [{"method": "bc", "train_seed": s, "env_seed": t, "reward": base, "steps": 900},
                     {"method": "other", "train_seed": s, "env_seed": t,
                      "reward": base + seed_gap, "steps": 900}]  # fmt: skip
    rows += [{"method": "expert", "train_seed": 0, "env_seed": t, "reward": 905.0 + track_effect[j],
              "steps": 900} for j, t in enumerate(tracks)]  # fmt: skip
    return pd.DataFrame(rows)


def test_a_seed_only_gap_gains_nothing_from_tracks(tmp_path):
    episodes = _episodes(np.random.default_rng(0))
    tables = eval_budget.comparisons(episodes, "bc", "expert", "reward")
    assert set(tables) == {"bc", "bc - expert", "other - bc"}
    gap = VarianceComponents.of(tables["other - bc"])
    assert gap.seed > 100 * gap.track and gap.residual < 1e-9  # the gap is the seed's alone
    assert VarianceComponents.of(tables["bc"]).track > 100  # shared tracks vary plain BC

    ep_path, bench_path = tmp_path / "episodes.parquet", tmp_path / "bench.parquet"
    write_table_atomic(ep_path, episodes, {"command": "test"})
    bench = pd.DataFrame({"case": ["train", "eval"], "variant": ["train_bc pipeline", "BC net"],
                          "unit": ["samples/s", "steps/s"], "value": [2000.0, 200.0]})  # fmt: skip
    write_table_atomic(bench_path, bench, {"provenance": {"git_revision": "abc"}})
    out = tmp_path / "budget"
    args = ["--episodes", str(ep_path), "--bench", str(bench_path), "--baseline", "bc",
            "--out", str(out)]  # fmt: skip
    assert eval_budget.main(args) == 0
    table, meta = read_table(out / "eval_budget.parquet")
    assert meta["train_seconds"] == pytest.approx(2000 * 64 / 2000.0)
    assert meta["episode_seconds"] == pytest.approx(900 / 200.0)
    other = table[table.comparison == "other - bc"]
    more_tracks = other[other.design == "tracks"].half_width.to_numpy()
    assert np.allclose(more_tracks, more_tracks[0], rtol=1e-6)  # tracks do not help a seed gap
    same = other[other.design == "same compute"]
    assert same.loc[same.half_width.idxmin(), "tracks"] == min(eval_budget.TRACKS)
    assert (out / "eval_budget.png").exists() and "other - bc" in (
        out / "eval_budget.md"
    ).read_text()
