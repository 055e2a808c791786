"""Synthetic demonstrations and tiny configs shared by the BC tests."""

from __future__ import annotations

import numpy as np

from safe_bc.bc import NetworkConfig, PreprocessConfig, TrainConfig
from safe_bc.data.demos import Demonstrations

TINY_CNN = NetworkConfig(channels=(4, 8), kernel_sizes=(4, 3), strides=(4, 2), hidden=16)
TINY_MLP = NetworkConfig(hidden=32, mlp_layers=1)
SMALL_FRAMES = PreprocessConfig(resize=24, grayscale=True, crop_bar=True)


def make_demos(
    observations: np.ndarray,
    actions: np.ndarray,
    episode_len: int = 50,
    warmup: int = 0,
    seed: int = 0,
) -> Demonstrations:
    """Wrap arrays as episodes of ``episode_len`` steps with random costs."""
    n = len(actions)
    steps = np.arange(n) % episode_len
    episodes = np.arange(n) // episode_len
    costs = np.random.default_rng(seed).uniform(0, 40, (n, 3)).astype(np.float32)
    return Demonstrations(
        observations=observations,
        actions=actions.astype(np.float32),
        costs=costs,
        safety=(40 - costs).astype(np.float32),
        episode_ids=episodes.astype(np.int64),
        steps=steps.astype(np.int64),
        seeds=episodes.astype(np.int64),
        warmup=steps < warmup,
        safety_dims=("left", "front", "right"),
    )


def frame_demos(n: int = 200, seed: int = 0, warmup: int = 0) -> Demonstrations:
    """Grey frames with a bright 16x16 square; steer = +-0.5 by the square's side, gas = its
    brightness, brake = 0.2: a simple function of pixel regions."""
    rng = np.random.default_rng(seed)
    obs = np.full((n, 96, 96, 3), 100, np.uint8)
    right = rng.random(n) < 0.5
    level = rng.uniform(0.2, 1.0, n)
    for i in range(n):
        c0 = 60 if right[i] else 20
        obs[i, 30:46, c0 : c0 + 16] = int(255 * level[i])
    obs[:, 84:] = rng.integers(0, 256, (n, 12, 96, 3), dtype=np.uint8)  # noisy bar
    actions = np.stack([np.where(right, 0.5, -0.5), level, np.full(n, 0.2)], axis=1)
    return make_demos(obs, actions, warmup=warmup, seed=seed)


def vector_demos(n: int = 200, d: int = 5, seed: int = 0) -> Demonstrations:
    """Vectors with actions a linear function of them (offset and scaled features)."""
    rng = np.random.default_rng(seed)
    obs = (rng.normal(size=(n, d)) * 10 + 50).astype(np.float32)
    w = rng.normal(size=(d, 2)) / 10
    actions = (obs - 50) @ w
    return make_demos(obs, actions, seed=seed)


def small_train(batches: int = 20, **kw) -> TrainConfig:
    return TrainConfig(batches=batches, batch_size=16, log_every=10, num_threads=1, **kw)
