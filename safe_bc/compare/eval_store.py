"""Where a comparison's stored evaluation lives: a function of what made it, never of a folder.

A comparison cell's evaluation is stamped with everything that made it (the run or agent
identity, the tracks, the evaluation settings, the thresholds; see
:func:`safe_bc.compare.run.cell_stamp`). Its file is named by that stamp's content
key, ``OUT/stored_evaluations/<key>.parquet``: two comparisons (or two rows) that need the same
evaluation share one file, and two that need different ones can never write to the same
file, whatever runs folder they share.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

FOLDER = "stored_evaluations"
"""The stored evaluations' folder under a comparison's output folder."""
KEY_CHARS = 16
"""Hex characters of the key (64 bits of the SHA-256)."""


def canonical(stamp: dict[str, Any]) -> str:
    """``stamp`` as canonical JSON: sorted keys, no spaces (the text the key hashes)."""
    return json.dumps(stamp, sort_keys=True, separators=(",", ":"))


def evaluation_key(stamp: dict[str, Any]) -> str:
    """The content key of a stamp: the first :data:`KEY_CHARS` hex digits of the SHA-256 of
    its canonical JSON."""
    return hashlib.sha256(canonical(stamp).encode()).hexdigest()[:KEY_CHARS]


def episodes_path(out: Path, stamp: dict[str, Any]) -> Path:
    """The stored episodes of the evaluation ``stamp`` describes, under the output ``out``."""
    return Path(out) / FOLDER / f"{evaluation_key(stamp)}.parquet"


def steps_path(out: Path, stamp: dict[str, Any]) -> Path:
    """Its stored steps (the rows whose stamp has ``keep_steps``)."""
    return Path(out) / FOLDER / f"{evaluation_key(stamp)}.steps.parquet"
