"""Who made a result: package version, git revision, time. Recorded with every output."""

from __future__ import annotations

import datetime as _dt
import os
import platform
import subprocess
import sys
from pathlib import Path
from typing import Any

import safe_bc

_REPO = Path(__file__).resolve().parent.parent


def git_revision() -> str:
    """The checkout's commit, with ``-dirty`` when there are uncommitted changes to tracked files.

    Returns ``"unknown"`` outside a git checkout (e.g. an installed wheel).
    """
    try:
        rev = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=_REPO, capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=_REPO,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return f"{rev}-dirty" if dirty else rev


def provenance() -> dict[str, str]:
    """Version, revision, UTC creation time and machine of the current run."""
    return {
        "package_version": safe_bc.__version__,
        "git_revision": git_revision(),
        "created_utc": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "python": platform.python_version(),
        "machine": f"{platform.machine()} {platform.node()}",
        "cpus": str(os.cpu_count()),
    }


def run_metadata(**fields: Any) -> dict[str, Any]:
    """What a result table records: the command line, ``fields`` (seeds, configs) and
    :func:`provenance`."""
    return {"command": " ".join(sys.argv), **fields, **provenance()}
