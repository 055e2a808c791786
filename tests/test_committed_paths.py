"""Committed records name paths relative to the repository: no JSON file under ``results/``
records an absolute path of the machine that made it (a clone's folder, a home folder)."""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MACHINE_PATH = re.compile(r"(^|[ =])/(work|home|Users|root)/")
"""An absolute path on a machine: a word (or a ``--flag=`` value) starting so."""


def _strings(obj: object, key: str = "") -> list[tuple[str, str]]:
    if isinstance(obj, dict):
        return [pair for k, v in obj.items() for pair in _strings(v, k)]
    if isinstance(obj, list):
        return [pair for v in obj for pair in _strings(v, key)]
    return [(key, obj)] if isinstance(obj, str) else []


def test_no_committed_json_record_names_a_path_of_the_machine_that_made_it() -> None:
    listed = subprocess.run(
        ["git", "ls-files", "results/*.json"], cwd=ROOT, capture_output=True, text=True
    )
    if listed.returncode != 0:
        pytest.skip("not a git checkout")
    found = [
        f"{name}: {key} {value[:80]!r}"
        for name in listed.stdout.split()
        for key, value in _strings(json.loads((ROOT / name).read_text()))
        if MACHINE_PATH.search(value)
    ]
    assert not found, f"{len(found)} absolute path(s), e.g. " + "; ".join(found[:3])
