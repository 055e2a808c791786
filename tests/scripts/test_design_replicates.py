"""scripts/design_replicates.py: two designs' replicates, pooled and compared."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

from safe_bc.data.store import read_table, write_table_atomic
from safe_bc.metrics import clopper_pearson_upper
from scripts.design_replicates import main

REPO = Path(__file__).resolve().parents[2]


def _design(root: Path, shift: float, crossings: int, alphas: tuple[float, float]) -> Path:
    """Two replicates, 2 training seeds x 3 tracks each; the winner ``shift`` above the
    expert on every track, ``crossings`` of its first replicate's episodes beyond d_s."""
    verdicts = []
    for k in range(2):
        rdir = root / "replicates" / f"r{k}"
        rdir.mkdir(parents=True)
        (rdir / "best.json").write_text(json.dumps({"trial_id": "w"}))
        rows = []
        for s in (10 * k, 10 * k + 1):
            for t in range(3):
                track = 100 * s + t
                rows.append({"method": "expert", "train_seed": s, "env_seed": track,
                             "reward": 900.0 + t, "any_violation": 0.0})  # fmt: skip
                hit = float(k == 0 and len([r for r in rows if r["method"] == "w"]) < crossings)
                reward = 900.0 + t + shift + s % 2
                rows.append({"method": "w", "train_seed": s, "env_seed": track,
                             "reward": reward, "any_violation": hit})  # fmt: skip
        write_table_atomic(rdir / "final_episodes.parquet", pd.DataFrame(rows), {})
        verdicts.append({"replicate": k, "winner": "w", "winner_feasible": True,
                         "vs_expert": "above", "selection.alpha": alphas[k]})  # fmt: skip
    write_table_atomic(root / "replicates.parquet", pd.DataFrame(verdicts), {})
    return root


def test_pools_the_replicates_and_compares_the_designs(tmp_path: Path, capsys) -> None:
    old = _design(tmp_path / "old", 0.0, 0, (0.5, 0.1))
    new = _design(tmp_path / "new", 2.0, 3, (0.5, 0.2))  # replicate 0's winner is old's
    out = tmp_path / "cmp"
    assert main(["--design", f"old={old}", "--design", f"new={new}", "--out", str(out)]) == 0
    table, meta = read_table(out.with_suffix(".parquet"))
    rows = table.set_index("design")
    assert rows.loc["old", "d_reward"] == pytest.approx(0.5)  # half the seeds 1 above
    assert rows.loc["new", "d_reward"] == pytest.approx(2.5)
    assert rows.loc["new", "beyond_d_s"] == 3 and rows.loc["new", "episodes"] == 12
    assert rows.loc["new", "beyond_share_ucb"] == pytest.approx(clopper_pearson_upper(3, 12))
    assert rows.loc["new - old", "d_reward"] == pytest.approx(2.0)
    lo, hi = rows.loc["new - old", ["d_reward_lo", "d_reward_hi"]]
    assert lo <= 2.0 <= hi and rows.loc["new", "replicates_above"] == 2
    md = out.with_suffix(".md").read_text()
    assert "**new minus old:** winner minus expert +2.0" in md and "3/12" in md
    assert rows.loc["new - old", "same_winner"] == "r0" and "Replicates r0 chose" in md
    assert meta["designs"] == [["old", str(old)], ["new", str(new)]]
    capsys.readouterr()
    assert main(["--design", f"old={old}", "--design", f"x={tmp_path / 'none'}",
                 "--out", str(out)]) == 2  # fmt: skip
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "no replicates" in err and err.count("\n") == 1


def test_the_committed_comparison_re_derives() -> None:
    table, meta = read_table(REPO / "results/checks/make_tune/half/replicates.parquet")
    from scripts.design_replicates import compare, paired_episodes

    designs = {k: paired_episodes(REPO / v) for k, v in meta["designs"]}
    tables = {k: read_table(REPO / v / "replicates.parquet")[0] for k, v in meta["designs"]}
    pd.testing.assert_frame_equal(compare(designs, tables), table)


def test_the_committed_comparison_names_every_replicates_demonstrations() -> None:
    _, meta = read_table(REPO / "results/checks/make_tune/half/replicates.parquet")
    for label, _folder in meta["designs"]:
        inputs = meta["inputs"][label]
        assert len(inputs) == 3 and all(v["digest"].startswith("sha256:") for v in inputs.values())
