"""Environments: the CarRacing testbed with safety costs and the rehabilitation pathway.

The names load on first use (PEP 562): ``safe_bc.envs.config`` and the env modules import
without the task registry, which :func:`make_env` reads.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "ENV_IDS": "safe_bc.envs.factory",
    "EnvConfig": "safe_bc.envs.config",
    "make_env": "safe_bc.envs.factory",
    "register_envs": "safe_bc.envs.factory",
    "SAFETY_DIMS": "safe_bc.envs.safety",
    "costs_from_distances": "safe_bc.envs.safety",
    "pixel_distances": "safe_bc.envs.safety",
    "CarRacingSafety": "safe_bc.envs.wrappers",
    "DomainRandomizationError": "safe_bc.envs.wrappers",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'safe_bc.envs' has no attribute {name!r}")
