"""The study stage registry: every entry is complete, and the trial table has its metrics."""

from __future__ import annotations

import inspect
from dataclasses import fields

import pytest

from safe_bc.methods.stages import STAGES, stage_metrics, stage_of
from safe_bc.study.spec import StudySpec, trial_metrics


@pytest.mark.parametrize("name", list(STAGES))
def test_registry_entries_are_complete(name: str) -> None:
    """A stage names a ``StudySpec`` field (off by default), a runner with the stage
    signature, and the metrics its runner reports, which the trial table carries."""
    stage = STAGES[name]
    spec_fields = {f.name: f for f in fields(StudySpec)}
    assert stage.field in spec_fields, f"stage {name!r}: StudySpec has no field {stage.field!r}"
    assert spec_fields[stage.field].default is None, "a stage must be off unless a study sets it"
    runner = stage.load()
    params = list(inspect.signature(runner).parameters)
    assert params == ["config", "agent", "run_config", "demos", "env_id", "folder", "parallel"]
    assert inspect.signature(runner).parameters["parallel"].kind is inspect.Parameter.KEYWORD_ONLY
    assert stage.metrics and set(stage.summed) <= set(stage.metrics)
    assert set(stage.metrics) <= set(trial_metrics())
    assert stage_of(f"{stage.prefix}anything") == name


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
