"""Run one episode of a policy in an env built by :func:`safe_bc.envs.make_env`."""

from __future__ import annotations

from typing import Protocol

import gymnasium as gym
import numpy as np

from safe_bc.episode import Episode
from safe_bc.policy import Policy


class ActionPerturbation(Protocol):
    """Changes the executed action while the policy's own action is recorded."""

    def reset(self, rng: np.random.Generator) -> None:
        """Start a new episode."""

    def apply(
        self,
        action: np.ndarray,
        t: int,
        rng: np.random.Generator,
        safety: np.ndarray | None = None,
    ) -> np.ndarray:
        """Return the action to execute at step ``t``, shape ``(A,)``; ``safety`` is the
        current state's ``(S,)`` safety distances (a perturbation may back off near a limit)."""


def run_episode(
    env: gym.Env,
    policy: Policy,
    seed: int,
    rng: np.random.Generator,
    *,
    episode_id: int = 0,
    perturbation: ActionPerturbation | None = None,
    keep_observations: bool = True,
    max_steps: int | None = None,
) -> Episode:
    """Roll ``policy`` out for one episode on env seed ``seed``.

    The env must put ``safety``, ``cost``, ``warmup`` and ``offroad`` in ``info``
    (see :class:`safe_bc.envs.CarRacingSafety`). ``rng`` drives the policy's and
    the perturbation's randomness, nothing else.

    Args:
        keep_observations: store the ``(T, *obs_shape)`` observations; when False
            the episode holds a ``(T, 0)`` placeholder (evaluation needs no frames).
        max_steps: stop after this many steps (marked truncated) even if the env
            would go on.
    """
    obs, info = env.reset(seed=seed)
    policy.reset(env, rng)
    if perturbation is not None:
        perturbation.reset(rng)
    cols: dict[str, list] = {k: [] for k in ("obs", "act", "exe", "rew", "term", "trunc")}
    cols.update({k: [] for k in ("safety", "cost", "warmup", "offroad")})
    t = 0
    while True:
        action = np.asarray(policy.act(obs, env), dtype=np.float32)
        if perturbation is not None:
            executed = perturbation.apply(action, t, rng, info["safety"])
        else:
            executed = action
        executed = np.asarray(executed, dtype=np.float32)
        cols["obs"].append(obs if keep_observations else np.empty(0, np.uint8))
        for key in ("safety", "cost", "warmup", "offroad"):
            cols[key].append(info[key])
        cols["act"].append(action)
        cols["exe"].append(executed)
        obs, reward, terminated, truncated, info = env.step(executed)
        t += 1
        if max_steps is not None and t >= max_steps:
            truncated = True
        cols["rew"].append(reward)
        cols["term"].append(terminated)
        cols["trunc"].append(truncated)
        if terminated or truncated:
            break
    dims = _safety_dims(env)
    return Episode(
        episode_id=episode_id,
        seed=seed,
        observations=np.stack(cols["obs"]),
        actions=np.stack(cols["act"]),
        executed_actions=np.stack(cols["exe"]),
        rewards=np.asarray(cols["rew"], np.float32),
        terminated=np.asarray(cols["term"], bool),
        truncated=np.asarray(cols["trunc"], bool),
        safety=np.stack(cols["safety"]).astype(np.float32),
        costs=np.stack(cols["cost"]).astype(np.float32),
        warmup=np.asarray(cols["warmup"], bool),
        offroad=np.asarray(cols["offroad"], bool),
        safety_dims=tuple(dims),
    )


def _safety_dims(env: gym.Env) -> tuple[str, ...]:
    """Safety dimension names published by the env (any wrapper or the base env)."""
    try:
        return tuple(env.get_wrapper_attr("safety_dims"))
    except AttributeError:
        raise ValueError(
            "env publishes no safety_dims; build it with safe_bc.envs.make_env"
        ) from None
