"""Run one episode of a policy in an env built by :func:`safe_bc.envs.make_env`."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import gymnasium as gym
import numpy as np

from safe_bc.episode import Episode
from safe_bc.policy import BatchPolicy, Policy


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


def run_episodes_lockstep(
    envs: Sequence[gym.Env],
    policy: BatchPolicy,
    seeds: Sequence[int],
    *,
    max_steps: int | None = None,
) -> list[Episode]:
    """One episode per env, ``envs[i]`` on ``seeds[i]``, stepped together: each step one
    :meth:`BatchPolicy.act_slots` call for the episodes still running. Each episode is the
    one :func:`run_episode` gives for its seed (observations not kept, no perturbation),
    since the policy acts per slot as in its own episode and the envs share nothing."""
    if len(envs) != len(seeds):
        raise ValueError(f"{len(envs)} envs for {len(seeds)} seeds")
    starts = [env.reset(seed=s) for env, s in zip(envs, seeds, strict=True)]
    obs, infos = [o for o, _ in starts], [info for _, info in starts]
    policy.reset_slots(len(envs))
    keys = ("act", "rew", "term", "trunc", "safety", "cost", "warmup", "offroad")
    cols: list[dict[str, list]] = [{k: [] for k in keys} for _ in envs]
    running = list(range(len(envs)))
    t = 0
    while running:
        actions = policy.act_slots(np.stack([obs[i] for i in running]), np.asarray(running))
        still = []
        for i, action in zip(running, np.asarray(actions, np.float32), strict=True):
            c = cols[i]
            for key in ("safety", "cost", "warmup", "offroad"):
                c[key].append(infos[i][key])
            c["act"].append(action)
            obs[i], reward, terminated, truncated, infos[i] = envs[i].step(action)
            if max_steps is not None and t + 1 >= max_steps:
                truncated = True
            c["rew"].append(reward)
            c["term"].append(terminated)
            c["trunc"].append(truncated)
            if not (terminated or truncated):
                still.append(i)
        running = still
        t += 1
    episodes = []
    for env, seed, c in zip(envs, seeds, cols, strict=True):
        actions = np.stack(c["act"])
        episodes.append(
            Episode(
                episode_id=0,
                seed=seed,
                observations=np.empty((len(actions), 0), np.uint8),
                actions=actions,
                executed_actions=actions.copy(),
                rewards=np.asarray(c["rew"], np.float32),
                terminated=np.asarray(c["term"], bool),
                truncated=np.asarray(c["trunc"], bool),
                safety=np.stack(c["safety"]).astype(np.float32),
                costs=np.stack(c["cost"]).astype(np.float32),
                warmup=np.asarray(c["warmup"], bool),
                offroad=np.asarray(c["offroad"], bool),
                safety_dims=_safety_dims(env),
            )
        )
    return episodes


def _safety_dims(env: gym.Env) -> tuple[str, ...]:
    """Safety dimension names published by the env (any wrapper or the base env)."""
    try:
        return tuple(env.get_wrapper_attr("safety_dims"))
    except AttributeError:
        raise ValueError(
            "env publishes no safety_dims; build it with safe_bc.envs.make_env"
        ) from None
