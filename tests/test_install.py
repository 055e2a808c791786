"""Installing beside other tools: the package declares ranges, so safe_bc and
stable-baselines3 install into one fresh environment with ``pip check`` clean.

The environment is made as ``make install`` makes ``.venv``: no system site packages, pip
upgraded, the Makefile's torch first (read from its recipe), then the package, here with
stable-baselines3 beside it, from the package indexes pip is configured with."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def makefile_torch() -> str:
    """The ``torch==X`` requirement the Makefile installs first (``TORCH``, written once and
    installed first by every environment it builds)."""
    text = (ROOT / "Makefile").read_text()
    found = re.findall(r"^TORCH := (torch==[\w.+]+)$", text, re.M)
    assert len(found) == 1, found
    assert not re.findall(r"pip install -q torch==", text)  # no second spelling of the pin
    return found[0]


def test_the_package_pins_no_exact_runtime_version_and_the_makefile_pins_torch() -> None:
    """Ranges in the package, the exact torch in the Makefile's install only."""
    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    assert not [d for d in deps if "==" in d], deps
    torch = next(d for d in deps if re.match(r"torch\b", d))
    assert ">=" in torch and "<" in torch, torch
    assert makefile_torch() == "torch==2.13.0"


def _run(*cmd: str | Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(c) for c in cmd], capture_output=True, text=True, check=False)


@pytest.mark.slow
@pytest.mark.timeout(3600)
def test_safe_bc_and_stable_baselines3_install_together_with_pip_check_clean(tmp_path) -> None:
    source = tmp_path / "src"  # the package alone: the build writes nothing into the checkout
    source.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, source / name)
    shutil.copytree(ROOT / "safe_bc", source / "safe_bc", ignore=shutil.ignore_patterns("*.pyc"))
    venv = tmp_path / "venv"
    made = _run(sys.executable, "-m", "venv", venv)  # without --system-site-packages
    assert made.returncode == 0, made.stderr
    python = venv / "bin" / "python"
    for step in (
        ("--upgrade", "pip"),
        (makefile_torch(),),
        (source, "stable-baselines3"),
    ):
        done = _run(python, "-m", "pip", "install", "-q", *step)
        assert done.returncode == 0, f"pip install {step}: {done.stderr[-3000:]}"
    check = _run(python, "-m", "pip", "check")
    assert check.returncode == 0, check.stdout + check.stderr
    both = _run(
        python, "-c", "import safe_bc, stable_baselines3; print(stable_baselines3.__version__)"
    )
    assert both.returncode == 0, both.stderr
