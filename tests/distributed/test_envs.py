"""Rollout envs on Ray actors (safe_bc.distributed.envs): same steps, same runs, survives a
dead actor."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import ray
import torch

from safe_bc.distributed.envs import RayEnvs, ray_envs, split_envs
from safe_bc.methods.improve import LocalEnvs, improve
from tests.test_improve import TINY


@pytest.fixture(autouse=True)
def _ray(ray_session):
    return ray_session


def test_split_envs_covers_every_env_once():
    for n in range(1, 9):
        for w in range(1, 5):
            parts = split_envs(n, w)
            assert [i for p in parts for i in p] == list(range(n))
            assert len(parts) == min(n, w) and all(len(p) >= 1 for p in parts)
    with pytest.raises(ValueError, match="workers >= 1"):
        split_envs(3, 0)


def test_ray_envs_step_carracing_exactly_like_local_envs():
    """3 real CarRacing envs on 2 actors: frames, rewards, flags and costs equal in-process."""
    local, remote = LocalEnvs("CarRacing-v3", 3), RayEnvs("CarRacing-v3", 3, workers=2)
    try:
        assert len(remote) == 3 and len(remote.actors) == 2
        for a, b in zip(local.reset([5, 6, 7]), remote.reset([5, 6, 7]), strict=True):
            np.testing.assert_array_equal(a, b)
        rng = np.random.default_rng(0)
        for t in range(60):
            index = [0, 2] if t % 3 else [0, 1, 2]  # an env left out, as when its episode ends
            actions = rng.uniform([-1, 0, 0], [1, 1, 0.2], (len(index), 3)).astype(np.float32)
            for a, b in zip(local.step(index, actions), remote.step(index, actions), strict=True):
                np.testing.assert_array_equal(a[0], b[0])
                assert a[1:4] == b[1:4]
                np.testing.assert_array_equal(a[4], b[4])
    finally:
        local.close()
        remote.close()


def _history(out: Path) -> pd.DataFrame:
    return pd.read_parquet(out / "history.parquet").drop(columns="seconds")


def _weights(out: Path) -> dict[str, torch.Tensor]:
    return torch.load(out / "policy" / "weights.pt", weights_only=True)


def test_improvement_on_ray_envs_is_bit_identical_and_survives_a_dead_actor(
    rehab_start: Path, tmp_path: Path
):
    """The same run with in-process envs, with envs on 2 actors, and with one of those actors
    killed after the first iteration: identical histories and weights; the dead actor is
    replaced and the interrupted rollout run again."""
    local = improve(rehab_start, tmp_path / "local", TINY)
    remote = improve(rehab_start, tmp_path / "ray", TINY, envs=ray_envs(2))

    groups: list[RayEnvs] = []

    def recording(env_id: str, n: int) -> RayEnvs:
        groups.append(RayEnvs(env_id, n, workers=2))
        return groups[-1]

    def kill_one(row: dict[str, float]) -> None:
        if row["iteration"] == 1:
            ray.kill(groups[0].actors[1], no_restart=True)

    killed = improve(rehab_start, tmp_path / "killed", TINY, envs=recording, on_iteration=kill_one)
    assert groups[0].restarts == 1
    for run in (remote, killed):
        pd.testing.assert_frame_equal(_history(run.out), _history(local.out), check_exact=True)
        a, b = _weights(run.out), _weights(local.out)
        assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def test_cli_rollout_workers_gives_the_in_process_run(rehab_start: Path, tmp_path: Path, capsys):
    from safe_bc.cli.commands import main

    base = ["improve", "--start", str(rehab_start), "--iterations", "2",
            "--episodes-per-iter", "4", "--quiet"]  # fmt: skip
    assert main([*base, "--out", str(tmp_path / "local")]) == 0
    assert main([*base, "--out", str(tmp_path / "ray"), "--rollout-workers", "2"]) == 0
    a, b = _weights(tmp_path / "local"), _weights(tmp_path / "ray")
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    assert "2 iterations" in capsys.readouterr().out
