"""Parallel collection on real CarRacing: resume, determinism, worker death, CLI errors."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import numpy as np
import psutil
import pytest

from safe_bc.cli.commands import main
from safe_bc.data.store import read_episodes
from safe_bc.distributed.collect import collect
from safe_bc.rollout.collect import CollectConfig

STEPS = 70


def config(episodes: int, workers: int = 2, seed: int = 0, max_steps: int = STEPS):
    return CollectConfig(episodes=episodes, workers=workers, seed=seed, max_steps=max_steps)


@pytest.fixture(scope="module")
def two_episodes(ray_session, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("demos") / "d"
    report = collect(config(2), out, progress=False)
    assert report.collected == [0, 1]
    return out


def test_files_per_episode_and_resume(two_episodes: Path, tmp_path: Path) -> None:
    files = sorted(p.name for p in (two_episodes / "episodes").iterdir())
    assert files == ["episode-00000.parquet", "episode-00001.parquet"]
    again = collect(config(2), two_episodes, progress=False)
    assert again.collected == [] and again.reused == [0, 1]
    more = collect(config(3), two_episodes, progress=False)
    assert more.collected == [2] and more.reused == [0, 1]
    eps = read_episodes(two_episodes)
    assert [e.episode_id for e in eps] == [0, 1, 2]
    assert all(len(e) == STEPS for e in eps)
    assert len({e.seed for e in eps}) == 3


def test_same_seed_same_data_whatever_the_workers(two_episodes: Path, tmp_path: Path) -> None:
    collect(config(2, workers=1), tmp_path / "one", progress=False)
    for a, b in zip(
        read_episodes(two_episodes, [0, 1]), read_episodes(tmp_path / "one"), strict=True
    ):
        np.testing.assert_array_equal(a.observations, b.observations)
        np.testing.assert_array_equal(a.actions, b.actions)
        np.testing.assert_array_equal(a.executed_actions, b.executed_actions)
        np.testing.assert_array_equal(a.costs, b.costs)


def _kill_first_busy_worker(stop: threading.Event, killed: list[int]) -> None:
    while not stop.is_set():
        for p in psutil.process_iter(["pid", "cmdline"]):
            cmd = " ".join(p.info["cmdline"] or [])
            if "RolloutWorker.run_episode" in cmd:
                time.sleep(0.3)  # let it get into the episode
                os.kill(p.info["pid"], signal.SIGKILL)
                killed.append(p.info["pid"])
                return
        time.sleep(0.05)


def test_dead_worker_is_replaced_and_episode_redone(two_episodes: Path, tmp_path: Path) -> None:
    stop, killed = threading.Event(), []
    killer = threading.Thread(target=_kill_first_busy_worker, args=(stop, killed))
    killer.start()
    try:
        report = collect(config(2, max_steps=200), tmp_path / "k", progress=False)
    finally:
        stop.set()
        killer.join()
    assert killed, "no worker was running an episode"
    assert report.worker_restarts >= 1
    assert report.collected == [0, 1]
    eps = read_episodes(tmp_path / "k")
    assert [len(e) for e in eps] == [200, 200]
    # the redone episode is the same episode it would have been
    first = read_episodes(two_episodes, [0])[0]
    np.testing.assert_array_equal(eps[0].actions[:STEPS], first.actions)


def test_cli_rejects_bad_arguments(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert main(["collect", "--episodes", "0", "--out", str(tmp_path / "x")]) == 2
    assert "safe-bc collect: error: episodes must be >= 1" in capsys.readouterr().err
    assert main(["collect", "--workers", "0"]) == 2
    assert "workers must be >= 1" in capsys.readouterr().err
    code = main(["collect", "--episodes", "1", "--out", str(tmp_path / "no" / "such" / "dir")])
    assert code == 2
    assert "parent directory of --out does not exist" in capsys.readouterr().err


def test_cli_reports_corrupt_file_in_one_line(
    two_episodes: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import shutil

    copy = tmp_path / "c"
    shutil.copytree(two_episodes, copy)
    bad = copy / "episodes" / "episode-00001.parquet"
    bad.write_bytes(bad.read_bytes()[:100])
    code = main(["collect", "--episodes", "2", "--max-steps", str(STEPS), "--out", str(copy)])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and "episode-00001.parquet" in err


def test_ensure_demos_refuses_another_collection_and_reads_a_complete_one(
    ray_session, tmp_path: Path
) -> None:
    from safe_bc.data.store import DatasetError
    from safe_bc.distributed.collect import ensure_demos

    two_episodes = tmp_path / "d"
    assert ensure_demos(two_episodes, config(2), progress=False).collected == [0, 1]
    report = ensure_demos(two_episodes, config(2), progress=False)
    assert report.collected == [] and report.reused == [0, 1]
    before = {p: p.stat().st_mtime_ns for p in two_episodes.rglob("*") if p.is_file()}
    two_episodes.chmod(0o555)  # a complete set in a read-only folder is used as it is
    try:
        assert ensure_demos(two_episodes, config(2), progress=False).reused == [0, 1]
    finally:
        two_episodes.chmod(0o755)
    assert {p: p.stat().st_mtime_ns for p in two_episodes.rglob("*") if p.is_file()} == before
    others = [
        (config(2, seed=3), "seed 0 -> 3"),
        (config(1), "episodes 2 -> 1"),
        (config(2, max_steps=STEPS + 1), f"max_steps {STEPS} -> {STEPS + 1}"),
    ]
    for other, named in others:
        with pytest.raises(DatasetError, match="collected with other settings") as e:
            ensure_demos(two_episodes, other, progress=False)
        assert named in str(e.value) and "\n" not in str(e.value)
    assert {p: p.stat().st_mtime_ns for p in two_episodes.rglob("*") if p.is_file()} == before


def test_a_full_disk_while_collecting_is_one_line_and_the_rerun_resumes(
    ray_session, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    import errno

    import safe_bc.data.atomic as atomic

    out = tmp_path / "d"
    argv = ["collect", "--episodes", "2", "--workers", "1", "--max-steps", "30", "--out",
            str(out), "--quiet"]  # fmt: skip
    real = atomic.os.replace

    def full_on_the_second(src, dst):  # the second episode's file does not fit
        if str(dst).endswith("episode-00001.parquet"):
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(src, dst)

    monkeypatch.setattr(atomic.os, "replace", full_on_the_second)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "No space left on device" in err, err
    files = sorted(p.name for p in (out / "episodes").iterdir())
    assert files == ["episode-00000.parquet"]  # nothing half-written beside it
    monkeypatch.undo()
    assert main(argv) == 0  # space again: the rerun keeps episode 0 and collects episode 1
    assert [e.episode_id for e in read_episodes(out)] == [0, 1]
