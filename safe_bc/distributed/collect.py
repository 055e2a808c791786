"""Parallel demonstration collection: persistent Ray actors, one Parquet file per episode.

The driver hands episode ids to ``W`` long-lived :class:`RolloutWorker` actors and
writes each finished episode atomically. Rerunning resumes: stored episodes are
kept, missing ones collected. A worker that dies mid-episode is replaced and its
episode made again from scratch, so the dataset never holds a partial or
duplicated episode.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import ray

from safe_bc.data.episode import Episode
from safe_bc.data.locks import output_lock
from safe_bc.data.provenance import provenance
from safe_bc.data.store import (
    META_FILE,
    DatasetError,
    DatasetMeta,
    completed_episodes,
    init_dataset,
    read_meta,
    settings_mismatch,
    write_episode,
)
from safe_bc.distributed.pool import run_on_actors
from safe_bc.distributed.runtime import cpus_per_actor, ensure_ray
from safe_bc.progress import progress_bar
from safe_bc.rollout.collect import CollectConfig, EpisodeMaker, config_dict, env_facts
from safe_bc.tasks import frames_renderer


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
    meta: DatasetMeta
    """The dataset's metadata as stored (the first collection's provenance on resume)."""

    @property
    def steps_per_s(self) -> float:
        """Collected env steps per wall-clock second."""
        return self.steps / self.seconds if self.seconds > 0 else float("nan")


def dataset_meta(config: CollectConfig) -> DatasetMeta:
    """The metadata a collection with ``config`` writes."""
    obs_shape, dims, bounds = env_facts(config)
    return DatasetMeta(
        env_id=config.env.env_id,
        obs_encoding=config.encoding,
        obs_shape=obs_shape,
        safety_dims=dims,
        seed=config.seed,
        max_steps=config.max_steps,
        expert=config_dict(config.expert),
        perturbation=config_dict(config.perturbation),
        provenance=provenance(),
        action_bounds=bounds,
        renderer=frames_renderer(config.env),
    )


def collect(
    config: CollectConfig,
    out: Path,
    *,
    progress: bool = True,
    max_retries: int = 3,
) -> CollectReport:
    """Collect ``config.episodes`` expert episodes into the dataset at ``out``.

    The dataset folder is locked for the whole call (:func:`safe_bc.data.locks.output_lock`): a
    second collection into the same folder is refused before it writes anything.

    Raises:
        DatasetError: ``out`` holds a dataset made with other settings or a bad file.
        OutputLockedError: another process is writing ``out``.
        RuntimeError: an episode's worker died more than ``max_retries`` times.
    """
    out = Path(out)
    if not out.parent.exists():
        raise FileNotFoundError(f"parent directory of --out does not exist: {out.parent}")
    return _collect(config, out, dataset_meta(config), progress=progress, max_retries=max_retries)


def _collect(
    config: CollectConfig, out: Path, expected: DatasetMeta, *, progress: bool, max_retries: int
) -> CollectReport:
    """:func:`collect` with the metadata the collection writes (``expected``) made: the
    dataset locked, made or checked, and its missing episodes collected."""
    with output_lock(out):
        meta = init_dataset(out, expected)
        done = set(completed_episodes(out, meta))
        todo = [i for i in range(config.episodes) if i not in done]
        reused = sorted(done & set(range(config.episodes)))
        report_args = dict(root=out, reused=reused, meta=meta)
        start = time.perf_counter()
        if not todo:
            return CollectReport(
                **report_args, collected=[], steps=0, seconds=0.0, worker_restarts=0
            )

        ensure_ray()
        collected: list[int] = []
        steps = 0
        bar = progress_bar(
            show=progress, total=config.episodes, initial=len(reused), desc="collect", unit="ep"
        )

        def store(eid: int, episode: Episode) -> None:
            nonlocal steps
            write_episode(out, episode, meta)
            collected.append(eid)
            steps += len(episode)
            bar.update(1)
            bar.set_postfix(steps_per_s=f"{steps / (time.perf_counter() - start):.0f}")

        worker_cls = RolloutWorker.options(
            num_cpus=cpus_per_actor(min(config.workers, len(todo))), max_restarts=0
        )
        with bar:
            restarts = run_on_actors(
                lambda: worker_cls.remote(config),
                config.workers,
                todo,
                lambda actor, eid: actor.run_episode.remote(eid),
                store,
                max_retries=max_retries,
                on_restart=lambda slot, eid: bar.write(
                    f"worker {slot} died during episode {eid}; replaced, episode restarted"
                ),
            )
        return CollectReport(
            **report_args,
            collected=sorted(collected),
            steps=steps,
            seconds=time.perf_counter() - start,
            worker_restarts=restarts,
        )


def ensure_demos(
    out: Path, config: CollectConfig | None = None, *, progress: bool = True
) -> CollectReport:
    """Make sure ``out`` holds the demonstration set ``config`` makes (default
    ``CollectConfig()``, comparable to the paper's ~4,700 pairs from 5 episodes): built when
    absent, resumed when interrupted, used as it is when complete (then nothing is written, so
    a read-only folder works).

    Raises:
        DatasetError: one line, before any work, when ``out`` holds a set made with other
            collector settings (renderer, expert, drift, seed, step cap, encoding) or more
            episodes than ``config`` makes: a run never trains on demonstrations other than
            those it expects.
    """
    out = Path(out)
    config = config or CollectConfig()
    expected = dataset_meta(config)
    if (out / META_FILE).exists():
        meta = read_meta(out)
        done = completed_episodes(out, meta)
        problem = settings_mismatch(meta, len(done), expected, config.episodes)
        if problem:
            raise DatasetError(
                f"{out}: these demonstrations were collected with other settings than this run "
                f"expects ({problem}); point the run at another folder, or move this one away "
                "and rerun to collect the expected set"
            )
        if len(done) >= config.episodes:
            return CollectReport(out, [], sorted(done), 0, 0.0, 0, meta)
    out.parent.mkdir(parents=True, exist_ok=True)
    return _collect(config, out, expected, progress=progress, max_retries=3)
