"""docs/tasks.md's complete example, run as written: its files (``# file: NAME`` blocks) are
built into a wheel that is unpacked onto the path (the module beside its ``dist-info`` with
the pyproject's entry points, as ``pip install`` leaves them), and its commands run through
the CLI in subprocesses (slow: the study with a tiny budget). The
default suite checks the registration through the entry point and a broken plug-in's one
line, exit 2."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DOC = REPO / "docs" / "tasks.md"


def doc_files() -> dict[str, str]:
    """``{file name: text}`` of the page's code blocks that start with ``# file: NAME``."""
    blocks = re.findall(r"```\w*\n# file: (\S+)\n(.*?)```", DOC.read_text(), re.S)
    return dict(blocks)


def doc_commands() -> list[str]:
    """The lines of the page's last bash block (comments cut) but ``pip install``, which
    :func:`install` stands in for."""
    block = re.findall(r"```bash\n(.*?)```", DOC.read_text(), re.S)[-1]
    lines = [line.split("#", 1)[0].strip() for line in block.splitlines()]
    return [line for line in lines if line and not line.startswith("pip ")]


def install(root: Path, module: bool = True) -> Path:
    """The example package built from the page's files (``pip wheel``, setuptools from this
    environment, no network) and unpacked into ``root/site``: on ``sys.path`` it is what
    ``pip install`` leaves, the module beside its ``dist-info`` with the entry points
    (``module=False``: the module removed, a plug-in that cannot load)."""
    source, site = root / "source", root / "site"
    source.mkdir(parents=True)
    for name, text in doc_files().items():
        (source / name).write_text(text)
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-build-isolation", "--no-deps", "-q",
         "-w", str(root / "wheel"), str(source)],
        check=True, capture_output=True, timeout=300,
    )  # fmt: skip
    (wheel,) = (root / "wheel").glob("*.whl")
    with zipfile.ZipFile(wheel) as z:
        z.extractall(site)
    if not module:
        (site / "lane_task.py").unlink()
    return site


def cli(args: list[str], cwd: Path, site: Path, **env: str) -> subprocess.CompletedProcess:
    environ = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), str(site)]), **env}
    environ.pop("RAY_ADDRESS", None)
    return subprocess.run([sys.executable, "-m", "safe_bc.cli.commands", *args], cwd=cwd,
                          env=environ, capture_output=True, text=True, timeout=900)  # fmt: skip


def test_the_page_has_the_example_files_and_commands() -> None:
    assert {"lane_task.py", "pyproject.toml", "lane_study.py"} <= set(doc_files())
    commands = [c.split()[1] for c in doc_commands() if c.startswith("safe-bc ")]
    assert commands == ["collect", "train", "evaluate", "tune"]


def test_the_example_task_registers_through_its_entry_point(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from safe_bc.study.spec import load_study
    from safe_bc.tasks import TASKS, task_defaults, task_of

    site = install(tmp_path)
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.delenv("SAFE_BC_TASKS", raising=False)
    spec = task_defaults("lane")  # a miss: loads the entry point
    assert TASKS["lane"] is spec and spec.env.env_id == "lane_task/Lane-v0"
    assert task_of("lane_task/Lane-v0") == "lane"
    study = load_study(tmp_path / "source" / "lane_study.py")
    assert study.env == spec.env and study.critical_eps == spec.eps
    from safe_bc.rollout.collect import CollectConfig

    assert study.collect == CollectConfig.for_task(spec)


def test_a_plugin_that_cannot_load_is_one_line_exit_2(tmp_path: Path) -> None:
    site = install(tmp_path, module=False)
    proc = cli(["collect", "--env", "lane", "--out", "x"], tmp_path, site)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.count("\n") == 1, proc.stderr
    assert "safe-bc collect: error: task plug-in 'lane' (lane_task:SPEC" in proc.stderr
    assert "ModuleNotFoundError: No module named 'lane_task'" in proc.stderr
    assert not (tmp_path / "x").exists()

    empty = tmp_path / "empty"
    empty.mkdir()
    proc = cli(["collect", "--env", "lane"], tmp_path, empty, SAFE_BC_TASKS="no_such_tasks")
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert "task module 'no_such_tasks' ($SAFE_BC_TASKS) cannot be imported" in proc.stderr


TINY = {
    "collect": [],  # the 6 episodes of the task, which the study expects
    "train": ["--bc.train.batches", "50", "--quiet"],
    "evaluate": ["--episodes", "2", "--workers", "0", "--quiet"],
    "tune": ["--trials", "2", "--storage", "ray", "--max-concurrent", "2",
             "--cpus-per-trial", "0.5", "--set", "batches=30", "eval_episodes=2",
             "screen_episodes=1", "startup_trials=2", "final_candidates=1",
             "final_train_seeds=1", "final_episodes=2"],
}  # fmt: skip
"""Flags appended to the page's commands: a tiny budget."""


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_the_example_runs_through_the_cli_study_included(tmp_path: Path) -> None:
    from safe_bc.data.store import read_table

    site = install(tmp_path)
    work = tmp_path / "work"
    work.mkdir()
    (work / "lane_study.py").write_text(doc_files()["lane_study.py"])
    for command in doc_commands():
        if not command.startswith("safe-bc "):
            subprocess.run(command, shell=True, cwd=work, check=True)
            continue
        args = command.split()[1:]
        proc = cli([*args, *TINY[args[0]]], work, site)
        assert proc.returncode == 0, (command, proc.stdout[-2000:], proc.stderr[-3000:])
    assert (work / "data" / "lane_demos" / "dataset.json").exists()
    assert (work / "runs" / "lane" / "weights.pt").exists()
    trials, _ = read_table(work / "results" / "lane" / "trials.parquet")
    assert len(trials) == 2 and (trials["status"] != "error").all()
    assert (work / "results" / "lane" / "finished.json").exists()
