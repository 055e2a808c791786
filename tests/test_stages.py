"""The study's stages are the registered methods: every entry is complete, and the trial
table has its metrics; the old ``STAGES`` name answers the registry with a warning."""

from __future__ import annotations

import inspect
from dataclasses import fields

import pytest

from safe_bc.methods import METHODS
from safe_bc.methods.stages import run_stage, stage_metrics, stage_of
from safe_bc.study.spec import StudySpec, trial_metrics


def test_the_stage_runner_signature() -> None:
    params = list(inspect.signature(run_stage).parameters)
    assert params == [
        "method", "config", "agent", "run_config", "demos", "env_id", "folder", "parallel"
    ]  # fmt: skip
    assert (
        inspect.signature(run_stage).parameters["parallel"].kind is inspect.Parameter.KEYWORD_ONLY
    )


@pytest.mark.parametrize("name", list(METHODS))
def test_registry_entries_are_complete(name: str) -> None:
    """A built-in method names a ``StudySpec`` field (off by default), a runner, and the
    metrics its runner reports, which the trial table carries."""
    method = METHODS[name]
    spec_fields = {f.name: f for f in fields(StudySpec)}
    assert name in spec_fields, f"stage {name!r}: StudySpec has no field {name!r}"
    assert spec_fields[name].default is None, "a stage must be off unless a study sets it"
    assert callable(method.load())
    assert method.metrics and set(method.summed) <= set(method.metrics)
    assert set(method.metrics) <= set(trial_metrics())
    assert stage_of(f"{method.prefix}anything") == name


def test_the_old_stages_name_is_the_registry_with_a_warning() -> None:
    import safe_bc.methods.stages as stages
    from safe_bc import moved

    moved._warned.discard("safe_bc.methods.stages.STAGES")
    with pytest.warns(FutureWarning, match="STAGES moved to safe_bc.methods.METHODS"):
        assert stages.STAGES is METHODS
    with pytest.raises(AttributeError):
        stages.NOT_A_NAME  # noqa: B018


def test_stage_metrics_are_distinct_and_not_core_metrics() -> None:
    assert len(set(stage_metrics())) == len(stage_metrics())
    assert len(set(trial_metrics())) == len(trial_metrics())


def test_reading_study_files_imports_no_torch_and_no_runner() -> None:
    """Every study file reads without torch; runners (torch, RL) load only when a stage runs."""
    import subprocess
    import sys
    from pathlib import Path

    jobs = sorted(str(p) for p in (Path(__file__).parents[1] / "tune_jobs").glob("*.py"))
    code = (
        "import sys; from safe_bc.study.spec import load_study; "
        f"[load_study(f) for f in {jobs!r}]; "
        "print('torch' in sys.modules, any(m.startswith('safe_bc.methods.improve.stage') for m in "
        "sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False False"
