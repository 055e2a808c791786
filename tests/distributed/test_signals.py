"""Ctrl-C and SIGTERM in every phase of ``safe-bc tune``, as real signals to a real driver: to
the driver alone (``kill PID``) and to its whole process group (a terminal's Ctrl-C,
``timeout``, ``docker stop`` of a shell, ``kill -- -PGID``). Each stop is one line, exit 130
or 143 within seconds, no Ray process left behind, and the same command resumes.

The driver runs in a session of its own with a marker in its environment; every process it
starts (Ray's GCS, raylet and workers included) inherits the marker, which is how a leftover
is found even after it has left the driver's session.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Callable
from pathlib import Path

import pytest

from safe_bc.data.store import read_table
from tests.conftest import TINY_COLLECT
from tests.distributed.test_study_faults import _ended, _history_rows

REPO = Path(__file__).resolve().parents[2]
SMOKE = REPO / "tune_jobs" / "smoke.py"

STOP_S = 30.0
"""Longest a stop may take from the signal to the exit (measured 3-9 s on 2 busy cores; inside
``ray.init`` the rest of Ray's start counts too)."""

NOT_EXPECTED = (
    "Traceback",
    "Segmentation fault",
    "Fatal Python error",
    "*** SIG",  # Ray's C++ crash dump
    "Stop signal received",  # Tune's notice
    "Tuner.restore",  # Tune's advice
    "== Status ==",  # Tune's status table
    "Failed to connect to GCS",  # the driver outliving its cluster
)


def _tagged(tag: str) -> list[tuple[int, str]]:
    """Live processes whose environment holds ``tag``: the driver and everything it started."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            if tag.encode() not in (entry / "environ").read_bytes():
                continue
            state = (entry / "stat").read_text().rsplit(")", 1)[1].split()[0]
            name = (entry / "comm").read_text().strip()
        except OSError:
            continue
        if state != "Z":
            found.append((int(entry.name), name))
    return found


class Driver:
    """One ``safe-bc tune`` run whose output is read as it comes (bytes: tqdm's ``\\r``
    redraws are one terminal line)."""

    def __init__(self, command: list[str]) -> None:
        self.tag = f"SAFE_BC_SIGNAL_TEST={uuid.uuid4().hex}"
        env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
        env.update(RAY_AUTH_MODE="disabled", PYTHONUNBUFFERED="1")
        env.update([self.tag.split("=")])
        self.proc = subprocess.Popen(
            command, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
            start_new_session=True,
        )  # fmt: skip
        self.out = bytearray()
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        while chunk := self.proc.stdout.read1(4096):
            self.out += chunk

    @property
    def text(self) -> str:
        return self.out.decode(errors="replace")

    def wait_for(self, what: str, ready: Callable[[], bool], timeout: float = 400) -> None:
        deadline = time.monotonic() + timeout
        while not ready():
            assert self.proc.poll() is None, f"ended before {what}:\n{self.text[-3000:]}"
            assert time.monotonic() < deadline, f"no {what} in time:\n{self.text[-3000:]}"
            time.sleep(0.02)

    def wait_for_process(self, name: str) -> None:
        self.wait_for(name, lambda: any(n == name for _, n in _tagged(self.tag)))

    def wait_for_line(self, pattern: str) -> None:
        self.wait_for(repr(pattern), lambda: re.search(pattern, self.text) is not None)

    def stop(self, signum: int, group: bool) -> tuple[int, float, list[str]]:
        """Send ``signum`` to the driver (or its group); its exit code, seconds to the exit
        and the terminal lines it began after the signal."""
        before = len(self.out)
        t0 = time.monotonic()
        (os.killpg if group else os.kill)(self.proc.pid, signum)
        try:
            code = self.proc.wait(timeout=120)
        except subprocess.TimeoutExpired:
            code = -1
        seconds = time.monotonic() - t0
        self.reader.join(10)
        after = bytes(self.out[before:])
        if before and not self.out[:before].endswith(b"\n"):  # a line under way (a tqdm bar)
            after = after.partition(b"\n")[2]
        lines = [line.rsplit(b"\r", 1)[-1].decode(errors="replace").rstrip() for line in
                 after.split(b"\n")]  # fmt: skip
        return code, seconds, [line for line in lines if line]

    def leftovers(self, wait: float = 10.0) -> list[tuple[int, str]]:
        """Processes of this run still alive ``wait`` seconds after its exit (then killed)."""
        deadline = time.monotonic() + wait
        while (left := _tagged(self.tag)) and time.monotonic() < deadline:
            time.sleep(0.2)
        for pid, _ in left:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        return left

    def kill(self) -> None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.wait()
        self.leftovers(wait=0)


PHASES = [
    # (phase, how to know the driver is there, seconds more, signal, to the whole group)
    ("ray.init", "gcs_server", 0.0, signal.SIGTERM, True),
    ("Ray started", r"Started a local Ray instance", 0.0, signal.SIGINT, False),
    ("trial loop, no trial reported", r"study 'smoke': up to", 2.0, signal.SIGTERM, False),
    ("trial loop", r"trial 1/\d+ ", 0.0, signal.SIGTERM, True),
    ("trial loop", r"trial 1/\d+ ", 0.0, signal.SIGINT, True),  # a terminal's Ctrl-C
    ("final phase", r"final phase: training", 0.0, signal.SIGTERM, False),
    ("certification", r"certification: seed 0", 0.0, signal.SIGINT, True),
]


@pytest.mark.slow
def test_every_phase_stops_in_one_line_on_either_signal_and_the_rerun_resumes(
    tiny_demos: Path, tmp_path: Path
) -> None:
    study_file = tmp_path / "tiny.py"
    study_file.write_text(
        "from dataclasses import replace\n"
        "from pathlib import Path\n"
        "from safe_bc.study.spec import load_study\n"
        "from safe_bc.rollout.collect import CollectConfig\n"
        f"STUDY = replace(load_study({str(SMOKE)!r}), demos=Path({str(tiny_demos)!r}),\n"
        f"    collect={TINY_COLLECT},\n"
        f"    results=Path({str(tmp_path / 'results')!r}), storage={str(tmp_path / 'ray')!r},\n"
        "    trials=5, max_concurrent=2, cpus_per_trial=1.0, batches=30, max_steps=80,\n"
        "    final_candidates=1, final_episodes=1, final_workers=0, certify_episodes=1)\n"
    )
    command = [sys.executable, "-m", "safe_bc.cli.commands", "tune", str(study_file)]
    out = tmp_path / "results" / "smoke"
    ended_before: set[str] = set()
    measured = []
    for number, (phase, marker, delay, signum, group) in enumerate(PHASES):
        driver = Driver(command)
        try:
            if marker == "gcs_server":  # inside ray.init: Ray's first process is up
                driver.wait_for_process(marker)
            else:
                driver.wait_for_line(marker)
            time.sleep(delay)
            if number >= 4:  # the experiment exists since the trial loop ran
                assert "resuming study" in driver.text, driver.text[-3000:]
            code, seconds, lines = driver.stop(signum, group)
        finally:
            driver.kill()
        name = signal.Signals(signum).name
        where = f"{name} to the {'group' if group else 'driver'} in {phase}"
        measured.append(f"{where}: exit {code} in {seconds:.1f} s")
        text = driver.text
        assert code == 128 + signum, f"{where}: exit {code}\n{text[-3000:]}"
        assert seconds < STOP_S, f"{where}: {seconds:.1f} s"
        lines = [line for line in lines if "Started a local Ray instance" not in line]
        one = f"safe-bc tune: stopped by {name}; "
        assert len(lines) == 1 and lines[0].startswith(one), f"{where}:\n" + "\n".join(lines)
        assert "rerun the same command" in lines[0]
        assert not [s for s in NOT_EXPECTED if s in text], f"{where}:\n{text[-3000:]}"
        assert not driver.leftovers(), f"{where}: Ray processes left"
        ended_before |= _ended(_history_rows(out / "history.jsonl"))

    # the run that finishes: a signal once it has printed its result does not interrupt it
    driver = Driver(command)
    try:
        driver.wait_for_line(r"\noutputs in ")
        code, seconds, lines = driver.stop(signal.SIGINT, group=True)
    finally:
        driver.kill()
    assert code in (0, 1) and lines == [], driver.text[-3000:]
    assert not [s for s in NOT_EXPECTED if s in driver.text], driver.text[-3000:]
    assert not driver.leftovers()
    assert (out / "finished.json").exists() and (out / "recommender").is_dir()
    trials, meta = read_table(out / "trials.parquet")
    assert meta["complete"] and len(trials) == 5 and trials["trial_id"].is_unique
    assert trials["status"].isin(["done", "stopped"]).all()
    # a trial whose end was saved before a stop was not trained again
    history, _ = read_table(out / "history.parquet")
    trained = history[history["phase"] == "trained"].groupby("trial_id").size()
    assert ended_before and all(trained[t] == 1 for t in ended_before), trained
    print("\n".join(measured))
