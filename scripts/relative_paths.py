"""Rewrite the committed JSON records under ``results/`` that name paths on the machine that
made them (``/work/<clone>/...``) relative to that clone, as the writers now record them
(:func:`safe_bc.provenance.command_line`, :func:`safe_bc.provenance.repo_relative`).

A sealed record is resealed by the project's own code: a checkpoint's ``config.json``
(``meta_sha256``, :func:`safe_bc.bc.checkpoint.with_meta_sha256`) and a recommender card
(``card_sha256``, :func:`safe_bc.recommender.card_digest`). Every file is written back in the
layout it had (indented or one line, with or without a final newline); a file this script would
not write back byte for byte unchanged is left alone and named.

Run: ``python -m scripts.relative_paths`` (prints what it rewrote).
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

from safe_bc.atomic import write_text_atomic
from safe_bc.bc.checkpoint import META_SHA256, with_meta_sha256
from safe_bc.provenance import command_line, repo_relative
from safe_bc.recommender import CARD_SHA256, card_digest

ROOT = Path(__file__).resolve().parents[1]
CLONE = re.compile(r"/work/[^/\s\"']+")
"""A clone's folder on the machines that made the committed results (``/work/<name>``)."""
PATH_KEYS = ("path", "experiment_path")
"""Keys whose value is one path."""


def relative(key: str, value: str) -> str:
    """``value`` (of ``key``) with the paths inside its clone relative to the clone.

    >>> relative("command", "/work/run/safe_bc/cli.py compare x.py --out /work/run/results/a")
    'safe-bc compare x.py --out results/a'
    >>> relative("path", "/work/rep/data/demos"), relative("path", "/tmp/x")
    ('data/demos', '/tmp/x')
    """
    clone = CLONE.match(value) or CLONE.search(value)
    if clone is None:
        return value
    if key == "command":
        return command_line(value.split(" "), clone.group(0))
    if key in PATH_KEYS:
        return repo_relative(value, clone.group(0))
    raise ValueError(f"{key}: {value!r} names a machine's path; teach relative() its kind")


def _walk(obj: Any, key: str = "") -> Any:
    if isinstance(obj, dict):
        return {k: _walk(v, k) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_walk(v, key) for v in obj]
    return relative(key, obj) if isinstance(obj, str) else obj


def _dumps_like(obj: Any, text: str) -> str:
    out = json.dumps(obj, indent=2 if text.startswith("{\n") else None, allow_nan=True)
    return out + ("\n" if text.endswith("\n") else "")


def rewrite(path: Path) -> bool:
    """Rewrite ``path`` with relative paths (resealed where sealed); whether it changed.

    Raises:
        ValueError: the file would not be written back as it is (its layout is not one this
            script writes).
    """
    text = path.read_text()
    data = json.loads(text)
    if _dumps_like(data, text) != text:
        raise ValueError(f"{path}: not in a layout this script writes back unchanged")
    new = _walk(data)
    if new == data:
        return False
    if META_SHA256 in new:
        new = with_meta_sha256(new)
    if CARD_SHA256 in new:
        new = {**new, CARD_SHA256: card_digest(new)}
    write_text_atomic(path, _dumps_like(new, text))
    return True


def committed_records(root: Path = ROOT) -> list[Path]:
    """The tracked JSON files under ``results/`` that name a clone's path."""
    names = subprocess.run(
        ["git", "grep", "-l", "/work/", "--", "results/*.json"],
        cwd=root, capture_output=True, text=True, check=False,
    ).stdout.split()  # fmt: skip
    return [root / n for n in names]


def main() -> int:
    changed, left = 0, []
    for path in committed_records():
        try:
            changed += rewrite(path)
        except ValueError as e:
            left.append(str(e))
    print(f"rewrote {changed} file(s)")
    for line in left:
        print(f"left alone: {line}")
    return 1 if left else 0


if __name__ == "__main__":
    sys.exit(main())
