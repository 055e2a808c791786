"""Results that runs of one runs folder share: work that candidates of
one training seed would otherwise repeat identically, stored once, content-keyed, in
``<runs folder>/_shared/<key>.json`` (written atomically) and read by the next run that needs
it.

The key (:func:`~safe_bc.methods.selfimprove.logic.content_key`) is the SHA-256 of everything
that made the result, in the run identity's own terms (the agent's weights digest and
configs or the expert's config, the env as the run identity writes it, the tracks and the
settings of the rollouts); the record holds those ingredients too and is read only when they
are the asker's. What is shared (:mod:`safe_bc.methods.selfimprove.run`): the start's
validation (the keep rule's baseline, the same for every candidate from one start) and the
expert's own runs on the training tracks (the bars of ``keep_against="expert"``, the same for
every such candidate of one seed). A run that reads a result records it as a hit
(``shared_hits``); its env steps stay what the run needed.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from safe_bc.data.atomic import write_json_atomic
from safe_bc.methods.selfimprove.logic import content_key

SHARED_FORMAT = "safe_bc.selfimprove.shared/1"
"""Format of a shared record (an ingredient of every key)."""


class SharedResults:
    """Content-keyed results in ``folder`` (``<key>.json``: the key, its ingredients, the
    value)."""

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)

    def path(self, ingredients: dict[str, Any]) -> Path:
        """Where the result of ``ingredients`` is stored."""
        return self.folder / f"{content_key(ingredients)}.json"

    def get(self, ingredients: dict[str, Any]) -> Any:
        """The stored value made by ``ingredients`` (``None``: none, or a record of other
        ingredients or unreadable: the caller computes it again)."""
        key = content_key(ingredients)
        try:
            record = json.loads((self.folder / f"{key}.json").read_text())
        except (OSError, ValueError):
            return None
        mine = json.loads(json.dumps(ingredients))
        if not isinstance(record, dict) or record.get("key") != key:
            return None
        if record.get("ingredients") != mine or "value" not in record:
            return None
        return record["value"]

    def put(self, ingredients: dict[str, Any], value: Any) -> None:
        """Store ``value`` as the result of ``ingredients`` (atomically)."""
        key = content_key(ingredients)
        record = {"format": SHARED_FORMAT, "key": key, "ingredients": ingredients, "value": value}
        write_json_atomic(self.folder / f"{key}.json", record, indent=None)


def expert_run_to_json(run: tuple[np.ndarray, float, int]) -> dict[str, Any]:
    """An expert's run (per-step rewards, total reward, steps) as JSON: every reward exactly
    (a float32 or float64 value is a float64 value, which JSON writes back exactly)."""
    rewards, total, steps = run
    rewards = np.asarray(rewards)
    return {
        "rewards": [float(x) for x in rewards],
        "dtype": rewards.dtype.str,
        "reward": float(total),
        "steps": int(steps),
    }


def expert_run_from_json(d: dict[str, Any]) -> tuple[np.ndarray, float, int]:
    """Inverse of :func:`expert_run_to_json`: the same arrays, bit for bit."""
    rewards = np.asarray(d["rewards"], dtype=np.float64).astype(np.dtype(d["dtype"]))
    return rewards, float(d["reward"]), int(d["steps"])
