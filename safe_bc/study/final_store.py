"""What the final phase has finished, kept under ``results/<study>/final_store/`` so that a
rerun (after a kill, a full disk, Ctrl-C) resumes from it instead of redoing it.

* ``agents/<key>/``: each retrained agent's checkpoint (a whole unit,
  :func:`safe_bc.bc.checkpoint.checkpoint_unit`), keyed by its run configuration (seed
  included) and the demonstrations;
* ``episodes/<key>.parquet``: each finished evaluation's episodes (one policy on one seed's
  block of fresh tracks), keyed by what the policy is and by the evaluation's settings.

Keys are SHA-256 digests of sorted JSON (:func:`key_of`), so they do not depend on Tune's
trial ids. Every file is written atomically; a file that does not load (a kill mid-write on a
file system without atomic renames) counts as missing and is made again.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import pandas as pd

from safe_bc.bc import CheckpointError, load_checkpoint
from safe_bc.bc.checkpoint import checkpoint_unit, save_checkpoint
from safe_bc.bc.net import BCNet
from safe_bc.data.store import DatasetError, read_table, write_table_atomic
from safe_bc.methods.experiment import RunConfig

STORE = "final_store"
"""The folder in ``results/<study>/``."""


def key_of(*parts: Any) -> str:
    """A short digest of ``parts`` (JSON, sorted keys; other objects by ``str``).

    >>> key_of({"b": 1, "a": 2}) == key_of({"a": 2, "b": 1})
    True
    """
    text = json.dumps(parts, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:24]


def agent_key(run: RunConfig, demos: str) -> str:
    """The key of the agent ``run`` trains on the demonstrations at ``demos``."""
    return key_of("agent", run.to_dict(), str(demos))


class FinalStore:
    """The final phase's finished agents and evaluations of one study."""

    def __init__(self, root: Path) -> None:
        self.root = Path(root)

    def agent(self, key: str) -> BCNet | None:
        """The stored agent of ``key`` (``None``: not finished)."""
        folder = self.root / "agents" / key
        if not folder.is_dir():
            return None
        try:
            return load_checkpoint(folder)[0]
        except (CheckpointError, OSError):
            return None

    def save_agent(self, key: str, model: BCNet, run: RunConfig) -> None:
        """Store a finished agent (atomically: the whole checkpoint or nothing)."""
        with checkpoint_unit(self.root / "agents" / key) as staging:
            save_checkpoint(staging, model, run.bc, extra={"run_config": run.to_dict()})

    def episodes(self, key: str) -> pd.DataFrame | None:
        """The stored episodes of evaluation ``key`` (``None``: not finished)."""
        path = self.root / "episodes" / f"{key}.parquet"
        if not path.exists():
            return None
        try:
            return read_table(path)[0]
        except DatasetError:
            return None

    def save_episodes(self, key: str, episodes: pd.DataFrame) -> None:
        """Store a finished evaluation's episodes (atomically)."""
        write_table_atomic(self.root / "episodes" / f"{key}.parquet", episodes)
