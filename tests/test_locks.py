"""One writer per output: collect, train, improve and tune hold their output's lock; a second
process gets one line naming the holder's pid and exit code 2, having written nothing; a
crashed holder releases it."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from safe_bc.cli.commands import main
from safe_bc.data.locks import OutputLockedError, lock_path, output_lock

REPO = Path(__file__).resolve().parents[1]
SMOKE = REPO / "tune_jobs" / "smoke.py"


def _listing(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


def test_a_second_holder_is_refused_with_the_holders_pid(tmp_path: Path) -> None:
    out = tmp_path / "out"
    with output_lock(out):
        assert lock_path(out).read_text().startswith(f"{os.getpid()} ")
        with pytest.raises(OutputLockedError) as info, output_lock(tmp_path / "." / "out"):
            pass
        message = str(info.value)
        assert f"pid {os.getpid()}" in message and str(out) in message and "\n" not in message
    assert not lock_path(out).exists()  # released and removed
    with output_lock(out):
        pass


def test_a_killed_holder_releases_the_lock(tmp_path: Path) -> None:
    out = tmp_path / "out"
    holder = textwrap.dedent(
        f"""
        import sys, time
        from safe_bc.data.locks import output_lock
        with output_lock({str(out)!r}):
            print("held", flush=True)
            time.sleep(120)
        """
    )
    proc = subprocess.Popen([sys.executable, "-c", holder], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "held"
        with pytest.raises(OutputLockedError, match=f"pid {proc.pid}"), output_lock(out):
            pass
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    assert lock_path(out).exists()  # left behind by the crash, but not held
    with output_lock(out):
        pass


def _refused(argv: list[str], held: Path, capsys: pytest.CaptureFixture) -> str:
    with output_lock(held):
        code = main(argv)
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count("\n") == 1 and f"pid {os.getpid()}" in err, err
    assert err.startswith(f"safe-bc {argv[0]}: error: ") and "another safe-bc process" in err
    return err


def test_collect_into_a_held_dataset_writes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    out = tmp_path / "demos"
    argv = ["collect", "--env", "rehab", "--episodes", "1", "--workers", "1", "--out", str(out),
            "--quiet"]  # fmt: skip
    _refused(argv, out, capsys)
    assert not out.exists() and _listing(tmp_path) == []


def test_train_into_a_held_checkpoint_writes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    out = tmp_path / "ckpt"
    _refused(["train", "--demos", str(tmp_path / "none"), "--out", str(out)], out, capsys)
    assert _listing(tmp_path) == []


@pytest.mark.parametrize("source", ["--checkpoint", "--recommender"])
def test_evaluate_into_a_held_folder_writes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture, source: str
) -> None:
    out = tmp_path / "eval"
    _refused(["evaluate", source, str(tmp_path / "none"), "--out", str(out)], out, capsys)
    assert _listing(tmp_path) == []


def test_improve_into_a_held_run_writes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    out = tmp_path / "run"
    argv = ["improve", "--start", str(tmp_path / "none"), "--out", str(out), "--quiet"]
    _refused(argv, out, capsys)
    assert _listing(tmp_path) == []


@pytest.mark.parametrize("held", ["results", "storage"])
def test_tune_on_a_held_study_writes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture, held: str
) -> None:
    results, storage = tmp_path / "results", tmp_path / "storage"
    target = results / "smoke" if held == "results" else storage / "smoke"
    argv = ["tune", str(SMOKE), "--results", str(results), "--storage", str(storage)]
    err = _refused(argv, target, capsys)
    assert f"--{held}" in err
    assert _listing(tmp_path) == []


@pytest.mark.slow
def test_two_collections_into_one_folder_never_mix(tmp_path: Path) -> None:
    """The issue's probe: two `collect` runs with different seeds into the same --out. One
    is refused (held, or other settings) and the dataset is the other's alone."""
    from safe_bc.data.store import read_episodes, read_meta

    env = {**os.environ, "RAY_AUTH_MODE": "disabled"}
    for k in range(3):
        out = tmp_path / f"r{k}"

        def run(seed: int, episodes: int, out: Path = out) -> subprocess.Popen:
            argv = [sys.executable, "-m", "safe_bc.cli.commands", "collect", "--env", "rehab",
                    "--episodes", str(episodes), "--workers", "1", "--seed", str(seed),
                    "--out", str(out), "--quiet"]  # fmt: skip
            return subprocess.Popen(argv, env=env, stderr=subprocess.PIPE, text=True)

        procs = [run(1, 4), run(2, 2)]
        codes = [p.wait(timeout=300) for p in procs]
        errs = [p.stderr.read() if p.stderr else "" for p in procs]
        assert sorted(codes) == [0, 2], errs
        loser = errs[codes.index(2)].strip()
        assert "\n" not in loser and ("another safe-bc process" in loser or "settings" in loser)
        meta = read_meta(out)
        episodes = read_episodes(out)
        assert len(episodes) == (4 if meta.seed == 1 else 2)


def test_a_folder_and_a_symlink_to_it_share_one_lock(tmp_path: Path) -> None:
    target = tmp_path / "real" / "study"
    target.mkdir(parents=True)
    link = tmp_path / "link"
    link.symlink_to(target)
    assert lock_path(link) == lock_path(target) == target.parent / ".study.lock"
    with (
        output_lock(target, "--results"),
        pytest.raises(OutputLockedError, match="being written"),
        output_lock(link, "--results"),
    ):
        pass
