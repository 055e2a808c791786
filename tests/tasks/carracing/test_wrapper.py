"""The CarRacing safety wrapper: env checker, info keys, refusals."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from safe_bc.tasks import make_env
from safe_bc.tasks.carracing.wrapper import CarRacingSafety, DomainRandomizationError
from safe_bc.tasks.env_config import EnvConfig


@pytest.mark.filterwarnings("ignore:.*is different from the unwrapped version")
def test_passes_env_checker() -> None:
    """The wrapper itself (not only the base env) passes gymnasium's checker."""
    env = CarRacingSafety(gym.make("CarRacing-v3").unwrapped)
    check_env(env, skip_render_check=True)
    env.close()


def test_info_keys_and_warmup_flag() -> None:
    env = make_env(EnvConfig(max_episode_steps=60))
    _, info = env.reset(seed=0)
    warm = [info["warmup"]]
    for _ in range(55):
        _, _, _, _, info = env.step(np.zeros(3, np.float32))
        warm.append(info["warmup"])
        assert info["safety"].shape == (3,) and info["cost"].dtype == np.float32
    env.close()
    # the zoom-in lasts 1 s of env time: 50 frames including the one from reset
    assert warm[:49] == [True] * 49 and not any(warm[50:])


def test_domain_randomize_is_refused() -> None:
    with pytest.raises(DomainRandomizationError, match="domain_randomize"):
        CarRacingSafety(gym.make("CarRacing-v3", domain_randomize=True))


def test_env_config_validation() -> None:
    with pytest.raises(ValueError, match="renderer"):
        EnvConfig(renderer="turbo")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="max_episode_steps"):
        EnvConfig(max_episode_steps=0)
