"""scripts/render_accuracy.py (formerly the measurement half of scripts/renderer_cost.py):
the factor rule, the frame comparison, and the committed results/ablation/renderer/ frames and
speed tables re-deriving the committed report's per-factor table and the chosen factor."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from safe_bc.data.store import read_table
from safe_bc.tasks.carracing.raster_render import DEFAULT_SUPERSAMPLE
from scripts.render_accuracy import choose_factor, frame_errors, per_factor

ROOT = Path(__file__).resolve().parents[2]
RENDERER = ROOT / "results/ablation/renderer"


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


def test_committed_frames_rederive_the_report_and_the_default_factor() -> None:
    """The per-factor table of the committed renderer.md from the committed frames and speeds
    (the speeds themselves are timings: not re-derivable), and the rule's choice from the
    committed frames is the one recorded and the raster env's default."""
    frames, meta = read_table(RENDERER / "frames.parquet")
    speed, _ = read_table(RENDERER / "speed.parquet")
    table = per_factor(frames, speed).to_markdown(index=False, floatfmt=".4g")
    assert table in (RENDERER / "renderer.md").read_text()
    assert choose_factor(frames) == meta["chosen"] == DEFAULT_SUPERSAMPLE


@pytest.mark.slow
def test_committed_frames_of_one_track_rerun_exactly() -> None:
    """The first committed drive, rerun: the same per-factor errors (the expert, the envs and
    the raster renderer are deterministic)."""
    committed, meta = read_table(RENDERER / "frames.parquet")
    track = meta["tracks"][0]
    frames, _ = frame_errors([track], tuple(meta["factors"]), meta["steps"],
                             np.asarray(meta["limits"], np.float32))  # fmt: skip
    want = committed[committed["track"] == track].reset_index(drop=True)
    pd.testing.assert_frame_equal(frames, want, check_dtype=False)
