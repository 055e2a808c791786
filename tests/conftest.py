"""Shared fixtures: one local Ray per test session, small CarRacing settings."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("RAY_AUTH_MODE", "disabled")
os.environ.setdefault("TUNE_DISABLE_AUTO_CALLBACK_LOGGERS", "1")
os.environ.setdefault("RAY_DEDUP_LOGS", "0")


@pytest.fixture(scope="session")
def ray_session():
    """A local 2-CPU Ray listening on loopback only, started once for every test that asks
    for it."""
    import ray

    from safe_bc.distributed.runtime import start_local_ray

    if not ray.is_initialized():
        # loopback only, like every local run (tests/distributed/test_runtime.py checks it)
        start_local_ray(num_cpus=2, log_to_driver=False, object_store_memory=256 * 2**20)
    yield ray
    ray.shutdown()


TINY_COLLECT = "CollectConfig(episodes=2, workers=2, max_steps=150)"
"""The collection of :func:`tiny_demos`, as a study file or a test writes it (a study that
reads the set must expect it: ``StudySpec(collect=...)``)."""


def tiny_collect():
    """:data:`TINY_COLLECT` as a config."""
    from safe_bc.rollout.collect import CollectConfig

    return eval(TINY_COLLECT, {"CollectConfig": CollectConfig})


@pytest.fixture(scope="session")
def tiny_demos(ray_session, tmp_path_factory):
    """Two short real CarRacing demonstration episodes (150 steps, ~100 scored)."""
    from safe_bc.distributed.collect import collect

    out = tmp_path_factory.mktemp("tiny") / "demos"
    collect(tiny_collect(), out, progress=False)
    return out


def rehab_collect():
    """The collection of :func:`rehab_demos` (a study or comparison reading it expects it)."""
    from safe_bc.rollout.collect import CollectConfig
    from safe_bc.tasks import task_defaults

    return CollectConfig.for_task(task_defaults("rehab"), episodes=8, workers=1)


@pytest.fixture(scope="session")
def rehab_demos(tmp_path_factory):
    """8 guideline rehab programmes, collected in-process (no Ray): the improvement tests'
    demonstrations."""
    from safe_bc.data.store import init_dataset, write_episode
    from safe_bc.distributed.collect import dataset_meta
    from safe_bc.rollout.collect import EpisodeMaker

    root = tmp_path_factory.mktemp("rehab") / "demos"
    cfg = rehab_collect()
    meta = init_dataset(root, dataset_meta(cfg))
    maker = EpisodeMaker(cfg)
    for i in range(cfg.episodes):
        write_episode(root, maker.make(i), meta)
    maker.close()
    return root


@pytest.fixture(scope="session")
def rehab_start(rehab_demos, tmp_path_factory):
    """A tiny safety-imitation start for improvement tests: the 8 guideline programmes, 50 BC
    batches, 16 hidden units."""
    from safe_bc.cli.commands import main

    ckpt = tmp_path_factory.mktemp("improve") / "start"
    argv = ["train", "--demos", str(rehab_demos), "--out", str(ckpt), "--bc.train.batches", "50",
            "--bc.network.hidden", "16", "--selection.alpha", "0.5", "--quiet"]  # fmt: skip
    assert main(argv) == 0
    return ckpt
