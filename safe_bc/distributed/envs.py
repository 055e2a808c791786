"""An improvement run's rollout envs on persistent Ray actors (:class:`RayEnvs`).

The learner (:class:`safe_bc.methods.improve.Improver`) keeps every decision: it picks the actions
of all live envs in one batched forward pass, with its own noise and shield, and sends each
actor the actions of its envs; the actors step their envs in parallel and send back the next
observations, rewards and costs. So the run is bit-identical to one with in-process envs
(:class:`safe_bc.methods.improve.LocalEnvs`), whatever the number of actors, and worth it where a
step costs milliseconds (CarRacing renders every frame) rather than microseconds (the
rehabilitation env, where the round trip dominates: keep that in-process).

An actor that dies mid-episode loses its envs' episodes: :meth:`RayEnvs.step` then raises
:class:`safe_bc.methods.improve.EnvsLostError`, the learner calls :meth:`RayEnvs.restart` (fresh
actors for the dead ones) and runs the whole rollout again from the same noise state.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from functools import partial

import numpy as np
import ray

from safe_bc.distributed.runtime import cpus_per_actor, ensure_ray
from safe_bc.methods.improve import EnvGroupFactory, EnvsLostError, LocalEnvs, StepOut


@ray.remote(max_restarts=0)
class _EnvSlice:
    """A contiguous slice of the group's envs, in one actor."""

    def __init__(self, env_id: str, n: int) -> None:
        self.envs = LocalEnvs(env_id, n)

    def ready(self) -> bool:
        return True

    def reset(self, seeds: Sequence[int]) -> list[np.ndarray]:
        return self.envs.reset(seeds)

    def step(self, index: Sequence[int], actions: np.ndarray) -> list[StepOut]:
        return self.envs.step(index, actions)


def split_envs(n: int, workers: int) -> list[range]:
    """Env indices ``0..n-1`` as ``min(n, workers)`` contiguous slices of near-equal size.

    >>> split_envs(5, 2)
    [range(0, 2), range(2, 5)]
    """
    if n < 1 or workers < 1:
        raise ValueError(f"need n >= 1 envs and workers >= 1, got n={n}, workers={workers}")
    k = min(n, workers)
    bounds = [round(i * n / k) for i in range(k + 1)]
    return [range(lo, hi) for lo, hi in itertools.pairwise(bounds)]


class RayEnvs:
    """``n`` envs spread over ``workers`` persistent Ray actors (an :class:`EnvGroup`).

    Args:
        env_id: the env (:func:`safe_bc.tasks.make_env`).
        n: number of envs.
        workers: actors (at most ``n``); each holds a contiguous slice of the envs.
        actor_cpus: each actor's CPU reservation; ``None`` shares the cluster's CPUs out
            (at most 1 each).
    """

    def __init__(self, env_id: str, n: int, workers: int, actor_cpus: float | None = None) -> None:
        ensure_ray()
        self.env_id, self.n = env_id, n
        self.slices = split_envs(n, workers)
        cpus = cpus_per_actor(len(self.slices)) if actor_cpus is None else actor_cpus
        self._actor_cls = _EnvSlice.options(num_cpus=cpus)
        self.owner = np.repeat(np.arange(len(self.slices)), [len(s) for s in self.slices])
        """``(n,)``: which actor holds env ``i``."""
        self.actors = [self._new(s) for s in self.slices]
        self.restarts = 0
        """Actors replaced so far."""
        ray.get([a.ready.remote() for a in self.actors])

    def _new(self, envs: range) -> ray.actor.ActorHandle:
        return self._actor_cls.remote(self.env_id, len(envs))

    def __len__(self) -> int:
        return self.n

    def _gather(self, refs: list[ray.ObjectRef]) -> list:
        try:
            return ray.get(refs)
        except ray.exceptions.RayActorError as e:
            raise EnvsLostError(f"a rollout actor died: {e}") from None

    def reset(self, seeds: Sequence[int]) -> list[np.ndarray]:
        if len(seeds) > self.n:
            raise ValueError(f"{len(seeds)} seeds for {self.n} envs")
        work = [
            (a, s) for a, s in zip(self.actors, self.slices, strict=True) if s.start < len(seeds)
        ]
        refs = [a.reset.remote(list(seeds[s.start : s.stop])) for a, s in work]
        return [np.array(obs) for part in self._gather(refs) for obs in part]

    def step(self, index: Sequence[int], actions: np.ndarray) -> list[StepOut]:
        index = np.asarray(index, int)
        owners = self.owner[index]
        refs, rows = [], []
        for k in np.unique(owners):
            mine = np.flatnonzero(owners == k)
            local = (index[mine] - self.slices[k].start).tolist()
            refs.append(self.actors[k].step.remote(local, actions[mine]))
            rows.append(mine)
        out: list[StepOut | None] = [None] * len(index)
        for mine, part in zip(rows, self._gather(refs), strict=True):
            for j, (nobs, r, term, trunc, cost) in zip(mine, part, strict=True):
                # Ray hands back read-only views of the object store: own copies
                out[j] = (np.array(nobs), r, term, trunc, np.array(cost))
        return out  # type: ignore[return-value]

    def restart(self) -> None:
        """Replace every actor that no longer answers (their envs start over)."""
        for k, actor in enumerate(self.actors):
            try:
                ray.get(actor.ready.remote())
            except ray.exceptions.RayActorError:
                self.actors[k] = self._new(self.slices[k])
                self.restarts += 1
        ray.get([a.ready.remote() for a in self.actors])

    def close(self) -> None:
        for actor in self.actors:
            ray.kill(actor, no_restart=True)
        self.actors = []


def ray_envs(workers: int, actor_cpus: float | None = None) -> EnvGroupFactory:
    """An :data:`~safe_bc.methods.improve.EnvGroupFactory` for
    :func:`safe_bc.methods.improve.improve`:
    its envs on ``workers`` Ray actors."""
    return partial(RayEnvs, workers=workers, actor_cpus=actor_cpus)


__all__ = ["RayEnvs", "ray_envs", "split_envs"]
