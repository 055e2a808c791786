"""Parallel demonstration collection: persistent Ray actors, one Parquet file per episode.

The driver hands episode ids to ``W`` long-lived :class:`RolloutWorker` actors and
writes each finished episode atomically. Rerunning resumes: stored episodes are
kept, missing ones collected. A worker that dies mid-episode is replaced and its
episode made again from scratch, so the dataset never holds a partial or
duplicated episode.
"""

from __future__ import annotations

import collections
import time
from dataclasses import dataclass
from pathlib import Path

import ray
from tqdm.auto import tqdm

from safe_bc.collection import CollectConfig, EpisodeMaker, config_dict, observation_shape
from safe_bc.data.store import DatasetMeta, completed_episodes, init_dataset, write_episode
from safe_bc.distributed.runtime import cpus_per_actor, ensure_ray
from safe_bc.episode import Episode
from safe_bc.provenance import provenance


@ray.remote
class RolloutWorker:
    """A long-lived actor holding one env and one expert."""

    def __init__(self, config: CollectConfig) -> None:
        self.maker = EpisodeMaker(config)

    def run_episode(self, episode_id: int) -> Episode:
        """Make demonstration episode ``episode_id``."""
        return self.maker.make(episode_id)


@dataclass(frozen=True)
class CollectReport:
    """What a collection run did."""

    root: Path
    collected: list[int]
    reused: list[int]
    steps: int
    seconds: float
    worker_restarts: int

    @property
    def steps_per_s(self) -> float:
        """Collected env steps per wall-clock second."""
        return self.steps / self.seconds if self.seconds > 0 else float("nan")


def dataset_meta(config: CollectConfig) -> DatasetMeta:
    """The metadata a collection with ``config`` writes."""
    from safe_bc.envs import SAFETY_DIMS

    dims = SAFETY_DIMS if config.env.is_carracing else _vector_dims(config)
    return DatasetMeta(
        env_id=config.env.env_id,
        obs_encoding=config.encoding,
        obs_shape=observation_shape(config),
        safety_dims=tuple(dims),
        seed=config.seed,
        max_steps=config.max_steps,
        expert=config_dict(config.expert),
        perturbation=config_dict(config.perturbation),
        provenance=provenance(),
    )


def _vector_dims(config: CollectConfig) -> tuple[str, ...]:
    from safe_bc.envs import make_env

    env = make_env(config.env)
    try:
        return tuple(env.get_wrapper_attr("safety_dims"))
    finally:
        env.close()


def collect(
    config: CollectConfig,
    out: Path,
    *,
    progress: bool = True,
    max_retries: int = 3,
) -> CollectReport:
    """Collect ``config.episodes`` expert episodes into the dataset at ``out``.

    Raises:
        DatasetError: ``out`` holds a dataset made with other settings or a bad file.
        RuntimeError: an episode's worker died more than ``max_retries`` times.
    """
    out = Path(out)
    if not out.parent.exists():
        raise FileNotFoundError(f"parent directory of --out does not exist: {out.parent}")
    meta = init_dataset(out, dataset_meta(config))
    done = set(completed_episodes(out, meta))
    todo = collections.deque(i for i in range(config.episodes) if i not in done)
    reused = sorted(done & set(range(config.episodes)))
    report_args = dict(root=out, reused=reused)
    start = time.perf_counter()
    if not todo:
        return CollectReport(**report_args, collected=[], steps=0, seconds=0.0, worker_restarts=0)

    ensure_ray()
    n_workers = min(config.workers, len(todo))
    worker_cls = RolloutWorker.options(num_cpus=cpus_per_actor(n_workers), max_restarts=0)
    workers = [worker_cls.remote(config) for _ in range(n_workers)]
    pending: dict[ray.ObjectRef, tuple[int, int]] = {}
    failures: collections.Counter[int] = collections.Counter()
    collected: list[int] = []
    steps = restarts = 0

    def submit(slot: int) -> None:
        if todo:
            eid = todo.popleft()
            pending[workers[slot].run_episode.remote(eid)] = (slot, eid)

    for slot in range(n_workers):
        submit(slot)
    bar = tqdm(
        total=config.episodes, initial=len(reused), desc="collect", unit="ep", disable=not progress
    )
    try:
        while pending:
            (ref,), _ = ray.wait(list(pending), num_returns=1)
            slot, eid = pending.pop(ref)
            try:
                episode = ray.get(ref)
            except ray.exceptions.RayActorError as e:
                failures[eid] += 1
                if failures[eid] > max_retries:
                    raise RuntimeError(
                        f"episode {eid}: rollout worker died {failures[eid]} times ({e})"
                    ) from None
                ray.kill(workers[slot], no_restart=True)
                workers[slot] = worker_cls.remote(config)
                restarts += 1
                todo.appendleft(eid)
                bar.write(f"worker {slot} died during episode {eid}; restarted, retrying")
            else:
                write_episode(out, episode, meta)
                collected.append(eid)
                steps += len(episode)
                bar.update(1)
                bar.set_postfix(steps_per_s=f"{steps / (time.perf_counter() - start):.0f}")
            submit(slot)
    finally:
        bar.close()
        for w in workers:
            ray.kill(w, no_restart=True)
    return CollectReport(
        **report_args,
        collected=sorted(collected),
        steps=steps,
        seconds=time.perf_counter() - start,
        worker_restarts=restarts,
    )
