"""Old module paths still import (the feature packages moved them): each answers with the new
module itself, warning once with its new home; the public names users rely on stay."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

from safe_bc.moved import MOVED, new_name


def run(code: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-W", "always", "-c", textwrap.dedent(code)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip


def test_every_old_path_imports_as_its_new_module():
    code = f"""
    import importlib, warnings
    warnings.simplefilter("ignore")
    for old, new in {dict(MOVED)!r}.items():
        assert importlib.import_module(old) is importlib.import_module(new), old
        assert importlib.import_module(new).__spec__.name == new, new
    """
    proc = run(code)
    assert proc.returncode == 0, proc.stderr[-2000:]


def test_an_old_path_warns_once_with_its_new_home():
    proc = run(
        """
        import safe_bc.distributed.study
        import safe_bc.distributed.study
        from safe_bc.compare_rows import Agent
        from safe_bc.compare.rows import Agent as New
        assert Agent is New
        """
    )
    assert proc.returncode == 0, proc.stderr
    lines = [x for x in proc.stderr.splitlines() if "FutureWarning" in x]
    assert len(lines) == 2, proc.stderr
    assert "safe_bc.distributed.study moved to safe_bc.study.run" in lines[0]
    assert "safe_bc.compare_rows moved to safe_bc.compare.rows" in lines[1]


def test_the_public_imports_users_rely_on():
    """``safe_bc.load_recommender``, ``safe_bc.tasks.make_env``, the gymnasium ids, the old
    names of docs/tasks.md's example, and a package that took a module's name."""
    proc = run(
        """
        import gymnasium as gym
        import safe_bc
        from safe_bc.study.recommender import load_recommender
        assert safe_bc.load_recommender is load_recommender
        from safe_bc.tasks import GymEnv, PerturbationConfig, TaskSpec, make_env, task_defaults
        from safe_bc.envs.config import EnvConfig
        from safe_bc.envs import EnvConfig as Handed
        from safe_bc.bc import BCConfig, NetworkConfig
        from safe_bc.collection import CollectConfig
        from safe_bc.run_config import RunConfig
        from safe_bc.study import Choice, Float, StudySpec
        from safe_bc.study import pareto_mask, trial_table
        from safe_bc.cli import main
        assert Handed is EnvConfig
        env = gym.make("safe_bc/RehabPathway-v0")
        env.close()
        """
    )
    assert proc.returncode == 0, proc.stderr[-2000:]


def test_new_names():
    assert new_name("safe_bc.selfimprove.run") == "safe_bc.methods.selfimprove.run"
    assert new_name("safe_bc.envs.info") == "safe_bc.tasks.info"
    assert new_name("safe_bc.study.run") is None and new_name("safe_bc.metrics") is None


def test_the_entry_point_group_and_console_script():
    from importlib.metadata import entry_points

    scripts = {e.name: e.value for e in entry_points(group="console_scripts")}
    if scripts.get("safe-bc") not in (None, "safe_bc.cli.commands:main"):
        pytest.fail(f"safe-bc points at {scripts['safe-bc']}: reinstall (make install)")
    from safe_bc.tasks.registry import ENTRY_POINTS

    assert ENTRY_POINTS == "safe_bc.tasks"


def test_the_old_method_commands_names_still_answer():
    """``safe-bc query`` and ``safe-bc improve``'s records and functions live beside their
    methods (``safe_bc.methods.METHOD_COMMANDS``); the command line's modules still hand them
    out by their names, ``ImproveMethod`` with a warning."""
    proc = run(
        """
        import dataclasses
        from safe_bc.cli.api import Done, improve, query
        from safe_bc.cli.jobs import ImproveJob, QueryJob
        from safe_bc.methods.improve.command import ImproveJob as Home
        from safe_bc.methods.queries.command import QueryJob as QueryHome
        assert ImproveJob is Home and QueryJob is QueryHome
        assert improve.args == ("improve",) and query.args == ("query",)
        from safe_bc.cli.jobs import ImproveMethod
        import safe_bc.cli.jobs as jobs
        assert not hasattr(jobs, "NoSuchJob")
        """
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    lines = [x for x in proc.stderr.splitlines() if "FutureWarning" in x]
    assert len(lines) == 1 and "safe_bc.methods.improve.command.ImproveMethod" in lines[0]
