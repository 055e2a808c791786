"""What every environment shares: :class:`EnvConfig`, the info contract (``info.py``) and
:func:`make_env`, which builds a task's env from the task registry. The tasks' own envs live
in their folders (``safe_bc/tasks/<name>/``).

The names load on first use (PEP 562): ``safe_bc.envs.config`` imports without the task
registry, which :func:`make_env` reads.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "ENV_IDS": "safe_bc.envs.factory",
    "EnvConfig": "safe_bc.envs.config",
    "make_env": "safe_bc.envs.factory",
    "register_envs": "safe_bc.envs.factory",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'safe_bc.envs' has no attribute {name!r}")
