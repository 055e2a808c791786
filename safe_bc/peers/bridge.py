"""A peer's exported actor (TorchScript, from ``peers/osrl_train.py``) as a safe_bc policy.

The actor maps an observation to an action in [-1, 1] (OSRL's ``max_action`` 1); the policy
maps it back to the dataset's action bounds (:func:`safe_bc.peers.data.from_unit`), which the
file's ``safe_bc.json`` records beside what trained it. safe_bc's evaluation runs it like any
other policy (:class:`ScriptedSource` is a policy source: ``build()``).
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from safe_bc.peers.data import from_unit

META = "safe_bc.json"
"""The name of the metadata an exported actor carries (TorchScript extra file)."""


def read_actor(path: str | Path) -> tuple[torch.jit.ScriptModule, dict[str, Any]]:
    """The TorchScript actor at ``path`` and its metadata."""
    extra = {META: ""}
    with warnings.catch_warnings():  # torch 2.13 deprecates TorchScript; it still loads
        warnings.filterwarnings("ignore", "`torch.jit.load` is deprecated", DeprecationWarning)
        module = torch.jit.load(str(path), map_location="cpu", _extra_files=extra)
    return module.eval(), json.loads(extra[META] or "{}")


class ScriptedPolicy:
    """A TorchScript actor acting on one observation at a time (deterministic)."""

    def __init__(self, module: torch.jit.ScriptModule, low: np.ndarray, high: np.ndarray) -> None:
        self.module = module
        self.low = np.asarray(low, np.float64)
        self.high = np.asarray(high, np.float64)

    def reset(self, env: gym.Env | None = None, rng: np.random.Generator | None = None) -> None:
        """Nothing to reset: the actor has no state."""

    @torch.no_grad()
    def act(self, obs: np.ndarray, env: gym.Env | None = None) -> np.ndarray:
        x = torch.as_tensor(np.asarray(obs, np.float32).reshape(1, -1))
        return from_unit(self.module(x)[0].numpy(), self.low, self.high)


@dataclass(frozen=True)
class ScriptedSource:
    """An exported actor file and the action bounds it acts in."""

    path: str
    """The TorchScript file."""
    low: tuple[float, ...]
    """The dataset's action lower bounds."""
    high: tuple[float, ...]
    """... and upper bounds."""

    @classmethod
    def from_file(cls, path: str | Path) -> ScriptedSource:
        """The source of the actor at ``path``, its bounds read from its metadata."""
        _, meta = read_actor(path)
        if "action_low" not in meta or "action_high" not in meta:
            raise ValueError(f"{path}: no action bounds in its {META}; export it again")
        return cls(str(path), tuple(meta["action_low"]), tuple(meta["action_high"]))

    def build(self) -> ScriptedPolicy:
        module, _ = read_actor(self.path)
        return ScriptedPolicy(module, np.asarray(self.low), np.asarray(self.high))


__all__ = ["META", "ScriptedPolicy", "ScriptedSource", "read_actor"]
