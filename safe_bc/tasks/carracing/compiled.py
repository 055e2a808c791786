"""The one switch for the CarRacing testbed's compiled (numba) kernels, and how they are loaded.

Three modules hold numba kernels, each a faster twin of numpy or pygame code that gives the
same results bit for bit: :mod:`.gfx_kernels` (the fast renderer's ``gfxdraw`` ports),
:mod:`.raster_kernels` (the raster renderer's vertex transforms) and :mod:`.ray_kernel` (the
safety rays of :func:`.costs.pixel_distances`). A module is imported on first use, and used,
only if numba is installed, :data:`COMPILED_ENV` is not ``0`` and its self-check (run once per
process) agrees with the code it replaces; otherwise that code runs, with a ``RuntimeWarning``
if the check failed (:func:`load_kernels` for the last two; ``fast_render._compiled_draw``,
with ``gfx_kernels.matches_pygame``, for the first). Numba and LLVM cost memory in every
process that loads them (``make bench``'s memory columns), which is what the switch is for.
"""

from __future__ import annotations

import importlib
import os
import warnings
from types import ModuleType

__all__ = ["COMPILED_ENV", "compiled_allowed", "load_kernels"]

COMPILED_ENV = "SAFE_BC_COMPILED_DRAWING"
"""Set to ``0`` to never import numba: the same frames and costs from numpy and pygame, slower
steps and less memory per process that renders CarRacing."""

_LOADED: dict[str, ModuleType | None] = {}


def compiled_allowed() -> bool:
    """False where :data:`COMPILED_ENV` is ``0``."""
    return os.environ.get(COMPILED_ENV, "1").strip() != "0"


def load_kernels(name: str) -> ModuleType | None:
    """``safe_bc.tasks.carracing.<name>`` if the kernels may and can be used (see the module
    docstring; its ``self_check()`` must return True), else None; resolved once per process."""
    if name not in _LOADED:
        module = None
        if compiled_allowed():
            try:
                module = importlib.import_module(f"safe_bc.tasks.carracing.{name}")
            except ImportError:  # numba is not installed
                module = None
            if module is not None and not module.self_check():
                warnings.warn(
                    f"safe_bc: the compiled kernels of {name} disagree with the code they "
                    "replace here; it runs instead (slower, same results)",
                    RuntimeWarning,
                    stacklevel=2,
                )
                module = None
        _LOADED[name] = module
    return _LOADED[name]
