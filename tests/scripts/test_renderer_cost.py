"""scripts/renderer_cost.py and renderer_pipeline.py: the factor rule, the frame comparison and
the input checks (the full runs are the committed results/ablation/renderer/)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from safe_bc.data.store import write_table_atomic
from scripts.renderer_cost import choose_factor, frame_errors
from scripts.renderer_pipeline import main as pipeline


def _frames(errors: dict[int, float]) -> pd.DataFrame:
    return pd.DataFrame({"factor": list(errors), "distance_px": list(errors.values())})


def test_rule_takes_the_fastest_factor_within_a_tenth_of_eps() -> None:
    assert choose_factor(_frames({1: 0.47, 2: 0.19, 4: 0.07}), eps=2.0) == 2
    assert choose_factor(_frames({1: 0.15, 2: 0.19, 4: 0.07}), eps=2.0) == 1
    assert choose_factor(_frames({1: 0.47, 2: 0.19, 4: 0.07}), eps=1.0) == 4
    with pytest.raises(SystemExit, match="no factor"):
        choose_factor(_frames({1: 0.47, 2: 0.3}), eps=2.0)


def test_frame_errors_follow_the_expert_in_every_env() -> None:
    limits = np.array([41.6, 49.3, 42.1], np.float32)
    frames, actions = frame_errors([3], (1, 4), steps=70, limits=limits)
    assert list(frames["factor"]) == [1, 4]
    # the zoom-in's first second (~48 steps at 50 fps) is not scored; the same steps per factor
    assert frames["steps"].nunique() == 1 and 15 < frames["steps"].iloc[0] < 25
    assert len(actions[3]) == 70
    assert frames["distance_px"].between(0.0, 5.0).all()
    assert frames["beyond_agree"].between(0.0, 1.0).all()
    # a finer canvas is closer to the exact frames
    assert frames.loc[1, "pixel_abs_diff"] < frames.loc[0, "pixel_abs_diff"]


def _exact_table(path: Path) -> Path:
    rows = pd.DataFrame({"method": ["a"] * 2, "train_seed": [0, 0], "env_seed": [5, 6],
                         "reward": [1.0, 2.0], "violation_steps": [0, 0]})  # fmt: skip
    meta = {"config": {"methods": {"a": {"alpha": 0.1}}, "demos": "data/demos", "episodes": 2}}
    write_table_atomic(path, rows, meta)
    return path


def test_pipeline_names_an_unknown_method(tmp_path: Path) -> None:
    table = _exact_table(tmp_path / "t.parquet")
    with pytest.raises(SystemExit, match="no method 'b'"):
        pipeline(["--exact", str(table), "--method", "b", "--data", str(tmp_path / "d")])


def test_pipeline_names_missing_training_seeds(tmp_path: Path) -> None:
    table = _exact_table(tmp_path / "t.parquet")
    with pytest.raises(SystemExit, match=r"training seeds \[1, 2\]"):
        pipeline(["--exact", str(table), "--method", "a", "--data", str(tmp_path / "d")])
