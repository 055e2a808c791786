"""The training tracks of a self-imitation round stepped in lockstep: every unperturbed and
pushed run of the round's tracks through a pool of envs, the agent's net called once per step
for every running run (``BatchPolicy.act_slots``). Each run keeps the driver the one-env path
gives it (:meth:`~safe_bc.methods.selfimprove.rollout.ExploreJob.driver`: the push behind its
back-off
zone, or the handover to the expert) with the net's action handed in; the expert's own run
stays one env at a time (a scripted expert has no net to batch).

``forward="rows"``: each run is bit for bit the one-env path's (:func:`run_episode`'s) on
any CPU, since the net still computes one row at a time and the envs share nothing;
``"batched"``: one forward pass over the running runs, faster, the same runs again for the
same seeds and pool width on the same machine type (:data:`safe_bc.policy.LockstepForward`).
No Ray: :meth:`ExploreJob.run` calls this."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

from safe_bc.data.episode import Episode
from safe_bc.policy import BatchPolicy, LockstepForward, Policy, check_lockstep_forward
from safe_bc.rollout.episode import SeesInfo, _Recorder


class GivenAction:
    """The agent as seen by one run's driver: :meth:`act` returns the action the pool's
    batched call computed for this run's current state."""

    def __init__(self) -> None:
        self.action: np.ndarray | None = None

    def reset(self, env: gym.Env | None = None, rng: np.random.Generator | None = None) -> None:
        self.action = None

    def act(self, obs: np.ndarray, env: gym.Env | None = None) -> np.ndarray:
        assert self.action is not None, "the pool sets the agent's action before the driver acts"
        return self.action


@dataclass
class Run:
    """One episode for the pool: its track, driver, push and generator."""

    seed: int
    """Track (patient) seed."""
    driver: Policy
    """What acts (built around :attr:`agent`)."""
    agent: GivenAction
    """The driver's agent."""
    rng: np.random.Generator
    """The episode's generator (the driver's and the push's)."""
    perturbation: Any = None
    """The push (``None``: unperturbed)."""
    keep_observations: bool = False
    """Store the frames (pushed runs: their kept rows are cut out)."""


class _Slot:
    """A run in progress in one env of the pool."""

    def __init__(self, index: int, run: Run, envs: Sequence[gym.Env], env_index: int) -> None:
        self.index, self.run, self.env_index = index, run, env_index
        self.env = env = envs[env_index]
        self.obs, self.info = env.reset(seed=run.seed)
        run.driver.reset(env, run.rng)
        if run.perturbation is not None:
            run.perturbation.reset(run.rng)
        self.rec = _Recorder(run.keep_observations)
        self.see = run.driver.see if isinstance(run.driver, SeesInfo) else None
        self.t = 0

    def step(self, own: np.ndarray, max_steps: int | None) -> bool:
        """Act with the net's action ``own`` as :func:`safe_bc.rollout.episode.run_episode` does;
        whether the episode goes on."""
        run = self.run
        run.agent.action = own
        action = np.asarray(run.driver.act(self.obs, self.env), dtype=np.float32)
        executed = action
        if run.perturbation is not None:
            executed = run.perturbation.apply(action, self.t, run.rng, self.info["safety"])
        executed = np.asarray(executed, dtype=np.float32)
        self.rec.before_step(self.obs, self.info, action, executed)
        self.obs, reward, terminated, truncated, self.info = self.env.step(executed)
        self.t += 1
        if max_steps is not None and self.t >= max_steps:
            truncated = True
        self.rec.after_step(reward, terminated, truncated, self.info)
        return not (terminated or truncated)


def run_pool(
    envs: Sequence[gym.Env],
    agent: BatchPolicy,
    runs: Sequence[Run],
    *,
    max_steps: int | None = None,
    forward: LockstepForward = "rows",
    on_done: Callable[[int, Episode], None] | None = None,
) -> list[Episode | None]:
    """Every run of ``runs`` through ``envs`` (a run starts in an env as soon as one is free,
    in list order), the agent called once per step for every running run, each run with its
    own slot (frame stack). ``on_done(i, episode)`` takes each finished episode; the list
    holds the episodes (``None`` where ``on_done`` was given, so that frames need not stay)."""
    check_lockstep_forward(forward, "forward")
    if not envs:
        raise ValueError("run_pool needs at least one env")
    agent.reset_slots(len(runs))
    out: list[Episode | None] = [None] * len(runs)
    free = list(range(len(envs)))[::-1]
    slots: list[_Slot] = []
    started = 0
    while slots or started < len(runs):
        while free and started < len(runs):
            slots.append(_Slot(started, runs[started], envs, free.pop()))
            started += 1
        for s in slots:
            if s.see is not None:
                s.see(s.info)
        own = agent.act_slots(
            np.stack([s.obs for s in slots]), np.asarray([s.index for s in slots]), forward
        )
        still = []
        for s, action in zip(slots, np.asarray(own, np.float32), strict=True):
            if s.step(action, max_steps):
                still.append(s)
                continue
            ep = s.rec.episode(s.env, s.run.seed, 0)
            if on_done is None:
                out[s.index] = ep
            else:
                on_done(s.index, ep)
            free.append(s.env_index)
        slots = still
    return out
