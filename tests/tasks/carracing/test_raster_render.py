"""RasterCarRacing: stock's state and dynamics, frames close to (not equal to) the exact ones."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from safe_bc.tasks import make_env
from safe_bc.tasks.carracing import RASTER_CARRACING_ID
from safe_bc.tasks.carracing.raster_render import RasterCarRacing
from safe_bc.tasks.env_config import EnvConfig

STEPS = 90  # the zoom-in ends at step 50; the rest is scored


def _actions(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    steer = np.clip(np.cumsum(rng.normal(0.0, 0.1, STEPS)), -0.6, 0.6)
    return np.stack([steer, np.full(STEPS, 0.4), np.zeros(STEPS)], axis=1).astype(np.float32)


def _drive(renderer: str, seed: int, **kw) -> tuple[list, list, list]:
    env = make_env(EnvConfig(renderer=renderer)) if not kw else gym.make(RASTER_CARRACING_ID, **kw)
    obs, info = env.reset(seed=seed)
    frames, infos, rewards = [obs], [info], []
    for a in _actions(seed):
        obs, r, *_, info = env.step(a)
        frames.append(obs)
        infos.append(info)
        rewards.append(r)
    env.close()
    return frames, infos, rewards


@pytest.fixture(scope="module")
def pair() -> tuple[tuple, tuple]:
    return _drive("fast", 4), _drive("raster", 4)


def test_same_dynamics_and_rewards(pair) -> None:
    (_, exact_info, exact_r), (_, raster_info, raster_r) = pair
    assert raster_r == exact_r  # rendering never feeds back into the physics
    assert [i["wheels_on_road"] for i in raster_info] == [i["wheels_on_road"] for i in exact_info]


def test_frames_and_costs_close_to_exact(pair) -> None:
    (exact, exact_info, _), (raster, raster_info, _) = pair
    scored = [k for k, i in enumerate(exact_info) if not i["warmup"]]
    assert len(scored) > 30
    diff = np.stack([np.abs(exact[k].astype(int) - raster[k].astype(int)) for k in scored])
    assert diff.mean() < 4.0  # edge anti-aliasing only: measured ~2 per channel
    assert (diff.max(axis=3) > 24).mean() < 0.05
    dist = np.stack([np.abs(exact_info[k]["safety"] - raster_info[k]["safety"]) for k in scored])
    assert dist.mean() < 0.5  # px; measured ~0.2 at the default factor
    assert not all(np.array_equal(exact[k], raster[k]) for k in scored)  # it is approximate


def test_indicator_panel_is_drawn_the_exact_way(pair) -> None:
    (exact, _, _), (raster, _, _) = pair
    for a, b in zip(exact, raster, strict=True):  # speed bar, wheel bars, score digits
        assert np.abs(a[84:].astype(int) - b[84:].astype(int)).max() <= 1


def test_deterministic_and_fresh_arrays() -> None:
    a, _, _ = _drive("raster", 9)
    b, _, _ = _drive("raster", 9)
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    assert len({id(f) for f in a}) == len(a)  # every step returns a new array
    assert all(f.shape == (96, 96, 3) and f.dtype == np.uint8 for f in a)


def test_supersample_one_returns_new_arrays() -> None:
    frames, _, _ = _drive("raster", 2, continuous=True, supersample=1, max_episode_steps=STEPS)
    assert len({id(f) for f in frames}) == len(frames)


@pytest.mark.parametrize("bad", [0, 17, 2.0])
def test_bad_supersample(bad) -> None:
    with pytest.raises(ValueError, match="supersample"):
        RasterCarRacing(supersample=bad)


def test_other_render_modes_are_exact() -> None:
    env = RasterCarRacing(render_mode="rgb_array")
    env.reset(seed=1)
    for a in _actions(1)[:5]:
        env.step(a)
    assert env.render().shape == (400, 600, 3)
    env.close()


def test_works_without_an_initialised_font_module() -> None:
    import pygame

    pygame.font.quit()  # a fresh process (an evaluation actor) has never initialised it
    env = make_env(EnvConfig(renderer="raster"))
    obs, _ = env.reset(seed=3)
    assert obs.shape == (96, 96, 3)
    env.close()


def test_renderer_name_checked() -> None:
    with pytest.raises(ValueError, match="renderer must be one of"):
        EnvConfig(renderer="pixel")  # type: ignore[arg-type]
