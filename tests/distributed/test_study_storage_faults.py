"""The storage failing under a real study (real drivers, real Ray): a full ``--storage`` in the
tuning loop stops the study in one line and the rerun loses no finished trial; a damaged
checkpoint of a trial in flight is named and the trial trained again."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from safe_bc.data.store import read_table
from tests.conftest import TINY_COLLECT
from tests.distributed.test_study_faults import REPO, SMOKE, _ended, _history_rows, _kill_session

pytestmark = pytest.mark.slow


def _study_file(tmp_path: Path, demos: Path, storage: Path, **fields: object) -> Path:
    study = tmp_path / "tiny.py"
    extra = "".join(f"    {k}={v!r},\n" for k, v in fields.items())
    study.write_text(
        "from dataclasses import replace\n"
        "from pathlib import Path\n"
        "from safe_bc.study.spec import load_study\n"
        "from safe_bc.rollout.collect import CollectConfig\n"
        f"STUDY = replace(load_study({str(SMOKE)!r}), demos=Path({str(demos)!r}),\n"
        f"    collect={TINY_COLLECT},\n"
        f"    results=Path({str(tmp_path / 'results')!r}), storage={str(storage)!r},\n"
        f"{extra}"
        "    max_concurrent=2, cpus_per_trial=1.0, batches=30, final_candidates=1,\n"
        "    final_episodes=2, final_train_seeds=1, final_workers=0)\n"
    )
    return study


def _env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    env["RAY_AUTH_MODE"] = "disabled"
    return env


def _tune(study: Path) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "safe_bc.cli.commands", "tune", str(study)]
    return subprocess.run(
        command, cwd=REPO, env=_env(), capture_output=True, text=True, timeout=900
    )


def _not_ours(output: str) -> list[str]:
    """Lines that are neither the study's own nor Ray's start-up line."""
    ours = ("study ", "trial ", "resuming study", "safe-bc tune: error: ")
    return [
        line
        for line in output.splitlines()
        if line.strip() and not line.startswith(ours) and "Started a local Ray instance" not in line
    ]


@pytest.fixture
def tmpfs(tmp_path: Path):
    """A 4 MiB tmpfs (a real file system that fills up); skipped where none can be mounted."""
    where = tmp_path / "tmpfs"
    where.mkdir()
    if shutil.which("mount") is None or os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    made = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=4m", "tmpfs", str(where)], capture_output=True
    )
    if made.returncode != 0:
        pytest.skip(f"no tmpfs here: {made.stderr.decode().strip()}")
    try:
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)], check=False)


@pytest.mark.timeout(1800)
def test_a_full_storage_in_the_loop_is_one_line_exit_2_and_the_rerun_loses_no_trial(
    tiny_demos: Path, tmp_path: Path, tmpfs: Path
) -> None:
    filler = tmpfs / "filler"
    filler.write_bytes(b"\0" * (4 * 2**20 - 1100 * 2**10))  # room for about four trials
    study = _study_file(tmp_path, tiny_demos, tmpfs / "ray", trials=8, max_steps=60,
                        screen_episodes=0)  # fmt: skip
    full = _tune(study)
    output = full.stdout + full.stderr
    assert full.returncode == 2, output[-3000:]
    errors = [line for line in output.splitlines() if line.startswith("safe-bc tune: error: ")]
    assert len(errors) == 1 and "No space left on device" in errors[0], output[-3000:]
    assert str(tmpfs / "ray") in errors[0] and errors[0].count("rerun the same command") == 1
    assert not _not_ours(output), output[-3000:]  # no traceback, no Tune error lines
    out = tmp_path / "results" / "smoke"
    rows = _history_rows(out / "history.jsonl")
    finished = _ended(rows)
    assert finished and not any(r.get("event") == "error" for r in rows)

    filler.unlink()  # space again: the same command resumes
    rerun = _tune(study)
    assert rerun.returncode in (0, 3), rerun.stdout[-3000:] + rerun.stderr[-3000:]
    assert "resuming study" in rerun.stdout
    trials, meta = read_table(out / "trials.parquet")
    assert meta["complete"] and len(trials) == 8 and trials["status"].eq("done").all()
    history, _ = read_table(out / "history.parquet")
    trained = history[history["phase"] == "trained"].groupby("trial_id").size()
    assert finished <= set(trials["trial_id"]) and (trained == 1).all(), trained


@pytest.mark.timeout(1800)
def test_a_damaged_checkpoint_of_a_trial_in_flight_is_named_and_the_trial_trained_again(
    tiny_demos: Path, tmp_path: Path
) -> None:
    study = _study_file(tmp_path, tiny_demos, tmp_path / "ray", trials=2, max_steps=300,
                        eval_episodes=4, screen_episodes=0)  # fmt: skip
    out, exp = tmp_path / "results" / "smoke", tmp_path / "ray" / "smoke"
    command = [sys.executable, "-m", "safe_bc.cli.commands", "tune", str(study)]
    with open(tmp_path / "first.log", "w") as sink:
        driver = subprocess.Popen(command, cwd=REPO, env=_env(), stdout=sink,
                                  stderr=subprocess.STDOUT, start_new_session=True)  # fmt: skip
        try:  # killed while a trained trial evaluates: its checkpoint is the one it resumes from
            deadline = time.monotonic() + 600
            while not (flight := _trained_in_flight(out, exp)):
                assert driver.poll() is None, (tmp_path / "first.log").read_text()[-3000:]
                assert time.monotonic() < deadline, "no trial trained in time"
                time.sleep(0.05)
        finally:
            _kill_session(driver.pid)
            driver.wait()
    tid, weights = flight
    weights.write_bytes(b"")
    rerun = _tune(study)
    output = rerun.stdout + rerun.stderr
    assert rerun.returncode in (0, 3), output[-3000:]
    named = [line for line in output.splitlines() if "its checkpoint is damaged" in line]
    assert len(named) == 1 and named[0].startswith(f"trial {tid}: ") and str(weights) in named[0]
    for noise in ("Traceback", "Trial task failed", "Tune retries it", "Error"):
        assert noise not in output, output[-3000:]  # the trial did not fail on it
    trials, meta = read_table(out / "trials.parquet")
    assert meta["complete"] and trials["status"].eq("done").all() and tid in set(trials["trial_id"])
    assert not (trials["error"] != "").any()


def _trained_in_flight(out: Path, exp: Path) -> tuple[str, Path] | None:
    """A trial that reported its trained row with a whole checkpoint but has not evaluated:
    ``(trial id, its weights.pt)``."""
    rows = _history_rows(out / "history.jsonl")
    done = {r["trial_id"] for r in rows if r.get("event") or r.get("phase") == "evaluated"}
    for tid in {r["trial_id"] for r in rows if r.get("phase") == "trained"} - done:
        for weights in sorted(exp.glob(f"trial_{tid}/checkpoint_*/weights.pt")):
            if (weights.parent / "config.json").exists():
                return tid, weights
    return None
