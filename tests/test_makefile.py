"""The Makefile's targets: what ``make demos`` writes (read with ``make -n``, nothing runs)."""

from __future__ import annotations

import shlex
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.skipif(shutil.which("make") is None, reason="needs make")


def _describe_out(*variables: str) -> str:
    """The ``--out`` of the ``safe-bc describe`` line ``make demos`` would run."""
    dry = subprocess.run(
        ["make", "-n", "-C", str(ROOT), "demos", *variables],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    lines = [line for line in dry.splitlines() if "safe-bc describe" in line]
    assert len(lines) == 1, dry
    words = shlex.split(lines[0])
    return words[words.index("--out") + 1]


def test_make_demos_describes_into_an_untracked_folder_by_default() -> None:
    out = _describe_out()
    assert not out.startswith("results/")
    if shutil.which("git") is None:
        pytest.skip("needs git")
    ignored = subprocess.run(
        ["git", "-C", str(ROOT), "check-ignore", "-q", f"{out}/summary.json"],
        check=False,
        capture_output=True,
    )
    if ignored.returncode == 128:  # not a git checkout (an unpacked archive)
        pytest.skip("not a git checkout")
    assert ignored.returncode == 0, f"{out} is not ignored by git"


def test_make_demos_rewrites_the_committed_description_only_when_asked() -> None:
    assert _describe_out("DESCRIBE=results/demos") == "results/demos"


def _tune_words(*variables: str) -> list[str]:
    """The ``safe-bc tune`` line ``make tune`` would run, as words."""
    dry = subprocess.run(
        ["make", "-n", "-C", str(ROOT), "tune", *variables],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    lines = [line for line in dry.splitlines() if "safe-bc tune" in line]
    assert len(lines) == 1, dry
    return shlex.split(lines[0])


def test_make_tune_with_another_trial_count_writes_folders_of_its_own() -> None:
    assert "--results" not in _tune_words() and "--storage" not in _tune_words()
    words = _tune_words("TRIALS=4")
    results, storage = words[words.index("--results") + 1], words[words.index("--storage") + 1]
    assert words[words.index("--trials") + 1] == "4"
    assert results == "runs/trials4" and storage.startswith("runs/trials4/")
