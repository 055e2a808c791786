"""Run one episode of a policy in an env built by :func:`safe_bc.tasks.make_env`."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import gymnasium as gym
import numpy as np

from safe_bc.data.episode import Episode
from safe_bc.policy import BatchPolicy, LockstepForward, Policy, check_lockstep_forward


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


@runtime_checkable
class SeesInfo(Protocol):
    """A policy that reads each state's ``info`` (its measured costs) before acting there."""

    def see(self, info: dict) -> None:
        """The ``info`` of the state the next :meth:`act` call acts in."""


_COLUMNS = ("obs", "act", "exe", "rew", "term", "trunc", "safety", "cost", "warmup", "offroad")


class _Recorder:
    """The columns of one episode as it runs, and the :class:`Episode` they make."""

    def __init__(self, keep_observations: bool) -> None:
        self.keep_observations = keep_observations
        self.cols: dict[str, list] = {k: [] for k in _COLUMNS}
        self.final_cost: np.ndarray | None = None

    def before_step(
        self, obs: np.ndarray, info: dict, action: np.ndarray, executed: np.ndarray
    ) -> None:
        """The state the policy acted in (its observation and ``info``) and both actions."""
        self.cols["obs"].append(obs if self.keep_observations else np.empty(0, np.uint8))
        for key in ("safety", "cost", "warmup", "offroad"):
            self.cols[key].append(info[key])
        self.cols["act"].append(action)
        self.cols["exe"].append(executed)

    def after_step(self, reward: float, terminated: bool, truncated: bool, info: dict) -> None:
        """What the env returned; ``info["cost"]`` is the outcome of the step (kept for the
        last step, whose outcome no later state records)."""
        self.final_cost = np.asarray(info["cost"], np.float32)
        self.cols["rew"].append(reward)
        self.cols["term"].append(terminated)
        self.cols["trunc"].append(truncated)

    def episode(self, env: gym.Env, seed: int, episode_id: int) -> Episode:
        c = self.cols
        return Episode(
            episode_id=episode_id,
            seed=seed,
            observations=np.stack(c["obs"]),
            actions=np.stack(c["act"]),
            executed_actions=np.stack(c["exe"]),
            rewards=np.asarray(c["rew"], np.float32),
            terminated=np.asarray(c["term"], bool),
            truncated=np.asarray(c["trunc"], bool),
            safety=np.stack(c["safety"]).astype(np.float32),
            costs=np.stack(c["cost"]).astype(np.float32),
            warmup=np.asarray(c["warmup"], bool),
            offroad=np.asarray(c["offroad"], bool),
            safety_dims=_safety_dims(env),
            final_cost=self.final_cost,
        )


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
    (the info contract, :mod:`safe_bc.tasks.info`). ``rng`` drives the policy's and the
    perturbation's randomness, nothing else.

    A policy with a ``see(info)`` method (a :class:`SeesInfo`: a wrapper that asks the expert
    or defers to it where the measured cost is critical) is shown each state's ``info`` just
    before it acts there.

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
    rec = _Recorder(keep_observations)
    see = policy.see if isinstance(policy, SeesInfo) else None
    t = 0
    while True:
        if see is not None:
            see(info)
        action = np.asarray(policy.act(obs, env), dtype=np.float32)
        if perturbation is not None:
            executed = perturbation.apply(action, t, rng, info["safety"])
        else:
            executed = action
        executed = np.asarray(executed, dtype=np.float32)
        rec.before_step(obs, info, action, executed)
        obs, reward, terminated, truncated, info = env.step(executed)
        t += 1
        if max_steps is not None and t >= max_steps:
            truncated = True
        rec.after_step(reward, terminated, truncated, info)
        if terminated or truncated:
            break
    return rec.episode(env, seed, episode_id)


def run_episodes_lockstep(
    envs: Sequence[gym.Env],
    policy: BatchPolicy,
    seeds: Sequence[int],
    *,
    max_steps: int | None = None,
    forward: LockstepForward = "rows",
) -> list[Episode]:
    """One episode per env, ``envs[i]`` on ``seeds[i]``, stepped together: each step one
    :meth:`BatchPolicy.act_slots` call for the episodes still running (observations not kept,
    no perturbation). A policy with ``start_slots(envs, seeds)`` and ``see_slots(infos,
    slots)`` (a handover to a privileged expert) is given the envs after their reset and each
    running slot's ``info`` before it acts.

    ``forward="rows"``: each episode is the one :func:`run_episode` gives for its seed, on
    any CPU, since the policy acts per slot as in its own episode (one-row forward passes)
    and the envs share nothing. ``"batched"``: one forward pass over the running episodes
    per step; the same episodes again for the same seeds and the same number of envs on the
    same machine type, not necessarily :func:`run_episode`'s
    (:data:`safe_bc.policy.LockstepForward`)."""
    check_lockstep_forward(forward, "forward")
    if len(envs) != len(seeds):
        raise ValueError(f"{len(envs)} envs for {len(seeds)} seeds")
    starts = [env.reset(seed=s) for env, s in zip(envs, seeds, strict=True)]
    obs, infos = [o for o, _ in starts], [info for _, info in starts]
    policy.reset_slots(len(envs))
    start = getattr(policy, "start_slots", None)  # a handover: its experts read the envs
    if start is not None:
        start(envs, seeds)
    see = getattr(policy, "see_slots", None)  # ... and each state's info
    recs = [_Recorder(keep_observations=False) for _ in envs]
    running = list(range(len(envs)))
    t = 0
    while running:
        if see is not None:
            see([infos[i] for i in running], np.asarray(running))
        actions = policy.act_slots(
            np.stack([obs[i] for i in running]), np.asarray(running), forward
        )
        still = []
        for i, action in zip(running, np.asarray(actions, np.float32), strict=True):
            recs[i].before_step(obs[i], infos[i], action, action)
            obs[i], reward, terminated, truncated, infos[i] = envs[i].step(action)
            if max_steps is not None and t + 1 >= max_steps:
                truncated = True
            recs[i].after_step(reward, terminated, truncated, infos[i])
            if not (terminated or truncated):
                still.append(i)
        running = still
        t += 1
    return [rec.episode(env, s, 0) for rec, env, s in zip(recs, envs, seeds, strict=True)]


def _safety_dims(env: gym.Env) -> tuple[str, ...]:
    """Safety dimension names published by the env (any wrapper or the base env)."""
    try:
        return tuple(env.get_wrapper_attr("safety_dims"))
    except AttributeError:
        raise ValueError(
            "env publishes no safety_dims; build it with safe_bc.tasks.make_env"
        ) from None
