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


CODE_PATHSPEC = (".", ":(exclude)results")
"""What a revision covers: every tracked file but the outputs under ``results/`` (a rerun
rewrites committed tables one by one; its own earlier outputs do not make the code
uncommitted)."""


def git_revision() -> str:
    """The checkout's commit, with ``-dirty`` when there are uncommitted changes to tracked
    files outside ``results/`` (:data:`CODE_PATHSPEC`).

    Returns ``"unknown"`` outside a git checkout (e.g. an installed wheel).
    """
    try:
        rev = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=_REPO, capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no", "--", *CODE_PATHSPEC],
            cwd=_REPO,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return f"{rev}-dirty" if dirty else rev


RESULTS = _REPO / "results"
"""The checkout's committed result folder: tables written here must come from a clean tree."""
ALLOW_DIRTY = "SAFE_BC_ALLOW_DIRTY"
"""Environment variable that lets a result table be written from a dirty tree: its value (a
reason, e.g. ``"draft rerun"``; ``0`` or empty does not count) is recorded in the table."""


class DirtyTreeError(RuntimeError):
    """A result table under ``results/`` was about to be written from uncommitted code."""


def _changed_files() -> list[str]:
    try:
        out = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no", "--", *CODE_PATHSPEC],
            cwd=_REPO, capture_output=True, text=True, check=True,
        ).stdout  # fmt: skip
    except (OSError, subprocess.CalledProcessError):
        return []
    return [line[3:] for line in out.splitlines() if line.strip()]


def check_result_write(path: str | Path) -> dict[str, Any] | None:
    """Refuse to write a result table under the checkout's ``results/`` from a dirty git tree
    (uncommitted changes to tracked files outside ``results/``: the table could not be
    re-derived from any commit; the command's own earlier tables do not count), unless
    ``$SAFE_BC_ALLOW_DIRTY`` says why; then return the record to embed in the table's metadata
    (``{"allowed_by": ..., "reason": ..., "changed_files": [...]}``).
    ``None``: nothing to record (a clean tree, a path elsewhere, e.g. a test's temporary
    folder, or no git checkout).

    Raises:
        DirtyTreeError: dirty tree, path under ``results/``, no ``$SAFE_BC_ALLOW_DIRTY``.
    """
    target = Path(path).resolve()
    if not target.is_relative_to(RESULTS.resolve()):
        return None
    changed = _changed_files()
    if not changed:
        return None
    reason = os.environ.get(ALLOW_DIRTY, "").strip()
    if reason in ("", "0"):
        shown = ", ".join(changed[:8]) + (
            f" (+{len(changed) - 8} more)" if len(changed) > 8 else ""
        )
        raise DirtyTreeError(
            f"refusing to write {path}: the git tree has uncommitted changes ({shown}), so the "
            f"table could not be re-derived from a commit; commit first, or set "
            f"{ALLOW_DIRTY}=<reason> to write it anyway (the reason and the changed files are "
            "recorded in the table)"
        )
    return {"allowed_by": ALLOW_DIRTY, "reason": reason, "changed_files": changed}


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
