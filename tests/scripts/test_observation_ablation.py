"""The observation ablation (scripts/observation_ablation.py): the steering-indicator region it
masks, the masked policy, and the table logic on a small synthetic episode table."""

from __future__ import annotations

import numpy as np
import pandas as pd

import scripts.observation_ablation as ablation
from safe_bc.bc.config import PreprocessConfig
from safe_bc.bc.preprocess import STEERING_INDICATOR, preprocess_frames
from safe_bc.envs import EnvConfig, make_env


def _steer(env, value: float, steps: int) -> np.ndarray:
    obs = None
    for _ in range(steps):
        obs, *_ = env.step(np.array([value, 0.0, 0.0], np.float32))
    return obs


def test_steering_indicator_lies_inside_the_masked_region():
    """Steer hard left, then hard right, on a real track: the green steering bar moves on both
    sides of column 48 and every pixel it lights lies inside STEERING_INDICATOR."""
    env = make_env(EnvConfig("CarRacing-v3"))
    try:
        env.reset(seed=123)
        for _ in range(60):  # past the zoom-in, some speed
            env.step(np.array([0.0, 0.3, 0.0], np.float32))
        left = _steer(env, -1.0, 8)
        right = _steer(env, 1.0, 16)
    finally:
        env.close()
    rows, cols = STEERING_INDICATOR
    for frame, side in ((left, "left"), (right, "right")):
        bar = frame[84:96].astype(int)
        green = (bar[..., 1] > 200) & (bar[..., 0] < 60) & (bar[..., 2] < 60)
        lit = np.nonzero(green[:, 30:])[1] + 30  # the steering/gyro half of the bar
        assert len(lit), f"no steering indicator lit when steering {side}"
        assert lit.min() >= cols.start and lit.max() < cols.stop, (side, lit.min(), lit.max())
        assert (lit < 48).any() if side == "left" else (lit > 48).any()
    assert rows == slice(84, 96)


class _Recorder:
    def __init__(self) -> None:
        self.seen: list[np.ndarray] = []

    def reset(self, env=None, rng=None) -> None:
        self.seen.clear()

    def act(self, obs, env=None) -> np.ndarray:
        self.seen.append(obs)
        return np.zeros(3, np.float32)


def test_masked_policy_blacks_out_only_the_indicator():
    inner = _Recorder()
    policy = ablation.MaskedSteering(inner)
    obs = np.full((96, 96, 3), 77, np.uint8)
    policy.reset()
    policy.act(obs)
    seen = inner.seen[0]
    assert (seen[STEERING_INDICATOR] == 0).all()
    outside = np.ones((96, 96), bool)
    outside[STEERING_INDICATOR] = False
    assert (seen[outside] == 77).all()
    assert (obs == 77).all()  # the caller's frame is untouched


def _episodes() -> pd.DataFrame:
    rng = np.random.default_rng(0)
    rows = []
    for cell, base, viol in (("nobar_grey_k1", 300.0, 1.0), ("bar_grey_k1", 900.0, 0.0)):
        for view in ("full", "steer_masked") if cell.startswith("bar") else ("full",):
            for seed in range(3):
                for track in range(5):
                    rows.append(
                        {"cell": cell, "view": view, "train_seed": seed, "env_seed": track,
                         "reward": base + rng.normal() - (50 if view != "full" else 0),
                         "any_violation": viol, "violation_steps": 10 * viol,
                         "offroad_steps": 0.0, "safety_mean": 5.0, "steer_autocorr": 0.9,
                         "steer_change": 0.01, "final_loss": 0.01}
                    )  # fmt: skip
    return pd.DataFrame(rows)


def test_summary_pairs_cells_and_chooses_the_safe_high_reward_cell():
    episodes = _episodes()
    summary, paired, copycat = ablation.summarise(episodes, "nobar_grey_k1")
    assert ablation.choose(summary) == "bar_grey_k1"
    row = paired.set_index("cell").loc["bar_grey_k1"]
    assert 590 < row["d_reward"] < 610 and row["d_reward_lo"] > 0
    masked = copycat.set_index("cell").loc["bar_grey_k1"]
    assert masked["d_reward_hi"] < 0  # masking cost reward in this synthetic table
    to_chosen = ablation.paired_crossed(
        episodes[episodes["view"] == "full"], "bar_grey_k1", ["reward", "violation_steps",
        "any_violation"], by="cell")  # fmt: skip
    text = ablation.markdown(summary, paired, to_chosen, copycat, episodes.assign(job_revision="r"),
                             {"batches": [2000], "seeds": [0, 1, 2], "episodes": 5,
                              "eval_seed": 10, "git_revision": "abc", "command": "x",
                              "eps": 2.0, "created_utc": "now", "cpus": "2",
                              "job_revisions": {"r": 40}},
                             "nobar_grey_k1", "bar_grey_k1", "T")  # fmt: skip
    assert "**bar_grey_k1**" in text and "0/15" in text and "15/15" in text


def test_mask_steering_preprocessing_equals_masking_the_frame():
    """Training with ``mask_steering`` sees what the evaluation-time mask shows."""
    frames = np.random.default_rng(0).integers(0, 256, (3, 96, 96, 3), dtype=np.uint8)
    masked = frames.copy()
    masked[:, 84:96, 36:62] = 0
    cfg = PreprocessConfig(crop_bar=False, mask_steering=True, grayscale=True)
    plain = PreprocessConfig(crop_bar=False, mask_steering=False, grayscale=True)
    assert preprocess_frames(frames, cfg).equal(preprocess_frames(masked, plain))
    assert not preprocess_frames(frames, plain).equal(preprocess_frames(masked, plain))
    assert ablation.cell_name(cfg) == "bar-nosteer_grey_k1"
    assert len(ablation.all_cells()) == 18


def test_the_preprocessing_default_is_the_committed_ablations_choice():
    """The default follows the measurement: change one and the other must follow."""
    from pathlib import Path

    from safe_bc.data.store import read_table

    table = Path(__file__).resolve().parents[2] / "results/ablation/observation/summary.parquet"
    summary, meta = read_table(table)
    assert ablation.cell_name(PreprocessConfig()) == meta["chosen"] == ablation.choose(summary)
    assert PreprocessConfig().frame_stack == 1 and PreprocessConfig().resize is None
