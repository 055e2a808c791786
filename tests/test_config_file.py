"""Running a config file by path: every failure is one line naming the file and the line."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from safe_bc.compare.families import family
from safe_bc.config_file import run_config_file


def _run(path: Path):
    return run_config_file(path, "study file", "tune_jobs/<name>.py", "safe_bc_test_cfg_")


def test_a_file_runs_as_a_module_kept_for_pickling(tmp_path: Path) -> None:
    f = tmp_path / "ok.py"
    f.write_text("X = 3\n")
    module = _run(f)
    assert module.X == 3
    assert sys.modules["safe_bc_test_cfg_ok"] is module


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("X = 1\nY = 1 / 0\n", r"bad\.py:2: ZeroDivisionError: division by zero$"),
        ("X = 1\n\ndef f(:\n", r"bad\.py:3: SyntaxError: "),
        ("import safe_bc_no_such_module\n", r"bad\.py:1: ModuleNotFoundError: "),
    ],
)
def test_a_failure_names_the_file_and_the_line(tmp_path: Path, text: str, expected: str) -> None:
    f = tmp_path / "bad.py"
    f.write_text(text)
    with pytest.raises(ValueError, match=expected):
        _run(f)
    assert "safe_bc_test_cfg_bad" not in sys.modules


def test_a_missing_or_non_python_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="no study file"):
        _run(tmp_path / "none.py")
    (tmp_path / "x.yaml").write_text("a: 1\n")
    with pytest.raises(ValueError, match=r"a study file is a Python file \(tune_jobs/<name>\.py\)"):
        _run(tmp_path / "x.yaml")


def test_a_family_file_reports_its_failing_line(tmp_path: Path) -> None:
    f = tmp_path / "fam.py"
    f.write_text("from safe_bc.compare.spec import Comparison\n\nCOMPARISONS = (Comparison(),)\n")
    with pytest.raises(ValueError, match=r"fam\.py:3: "):
        family(f)
