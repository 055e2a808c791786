"""Old module paths, kept importable: each warns once with its new home.

The package moved to feature folders (``docs/history.md``); :data:`MOVED` maps every old
module to its new one. :func:`install` (run by ``import safe_bc``) puts a finder on
``sys.meta_path`` that answers an old name with the new module itself (one object under both
names, so classes and their pickles stay one). :func:`forward` serves a package that took an
old module's name (``safe_bc.study`` was a module): old names read from it are forwarded to
the module that holds them now, with the same warning.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
import warnings
from collections.abc import Callable
from typing import Any

MOVED: dict[str, str] = {
    "safe_bc.api": "safe_bc.cli.api",
    "safe_bc.atomic": "safe_bc.data.atomic",
    "safe_bc.cli_help": "safe_bc.cli.help",
    "safe_bc.collection": "safe_bc.rollout.collect",
    "safe_bc.compare_rows": "safe_bc.compare.rows",
    "safe_bc.curves": "safe_bc.data.curves",
    "safe_bc.demos": "safe_bc.data.demos",
    "safe_bc.distributed.certify": "safe_bc.study.certify",
    "safe_bc.distributed.compare": "safe_bc.compare.run",
    "safe_bc.distributed.console": "safe_bc.study.console",
    "safe_bc.distributed.final": "safe_bc.study.final",
    "safe_bc.distributed.final_store": "safe_bc.study.final_store",
    "safe_bc.distributed.replicates": "safe_bc.study.run_replicates",
    "safe_bc.distributed.resume": "safe_bc.study.resume",
    "safe_bc.distributed.search": "safe_bc.study.search",
    "safe_bc.distributed.stop": "safe_bc.study.stop",
    "safe_bc.distributed.study": "safe_bc.study.run",
    "safe_bc.distributed.trial": "safe_bc.study.trial",
    "safe_bc.envs": "safe_bc.tasks",
    "safe_bc.envs.config": "safe_bc.tasks.env_config",
    "safe_bc.envs.info": "safe_bc.tasks.info",
    "safe_bc.episode": "safe_bc.data.episode",
    "safe_bc.eval_config": "safe_bc.rollout.config",
    "safe_bc.eval_store": "safe_bc.compare.eval_store",
    "safe_bc.evaluation": "safe_bc.rollout.evaluate",
    "safe_bc.experiment": "safe_bc.methods.experiment",
    "safe_bc.families": "safe_bc.compare.families",
    "safe_bc.handover_choice": "safe_bc.compare.handover_choice",
    "safe_bc.improve": "safe_bc.methods.improve",
    "safe_bc.jobs": "safe_bc.cli.jobs",
    "safe_bc.locks": "safe_bc.data.locks",
    "safe_bc.methods.queries.defer": "safe_bc.rollout.handover",
    "safe_bc.protocol": "safe_bc.compare.protocol",
    "safe_bc.provenance": "safe_bc.data.provenance",
    "safe_bc.queries": "safe_bc.methods.queries",
    "safe_bc.queries.defer": "safe_bc.rollout.handover",
    "safe_bc.recommender": "safe_bc.study.recommender",
    "safe_bc.replicates": "safe_bc.study.replicates",
    "safe_bc.reproduce": "safe_bc.compare.reproduce",
    "safe_bc.rounds": "safe_bc.methods.rounds",
    "safe_bc.selfimprove": "safe_bc.methods.selfimprove",
    "safe_bc.stages": "safe_bc.methods.stages",
    "safe_bc.study_plan": "safe_bc.study.plan",
    "safe_bc.tasks.carracing.release_sweep": "safe_bc.rollout.release_sweep",
    "safe_bc.timing": "safe_bc.study.timing",
}
"""Old module -> new module; an old package's submodules follow it by prefix."""

NAMES: dict[str, str] = {
    "safe_bc.methods.stages.STAGES": "safe_bc.methods.METHODS",
    "safe_bc.cli.jobs.ImproveMethod": "safe_bc.methods.improve.command.ImproveMethod",
}
"""Old public names of a module that stayed -> their new home (``module.name``): read from the
old module (:func:`names`), each warns once and answers the new object. ``STAGES`` (stage name
-> the method seen as a stage) is the registry itself now: its entries are the
:class:`safe_bc.methods.MethodSpec` records (``.name``, ``.prefix``, ``.metrics``,
``.reduce``), run as a stage by :func:`safe_bc.methods.stages.run_stage`. ``ImproveMethod``
(``safe-bc improve --method``'s values) lives beside that command's record."""

_warned: set[str] = set()


def _warn(old: str, new: str) -> None:
    if old not in _warned:
        _warned.add(old)
        warnings.warn(f"{old} moved to {new}: import it from there", FutureWarning, stacklevel=3)


def new_name(old: str) -> str | None:
    """The new name of module ``old``, or ``None`` when it did not move.

    >>> new_name("safe_bc.distributed.study"), new_name("safe_bc.improve.config")
    ('safe_bc.study.run', 'safe_bc.methods.improve.config')
    >>> new_name("safe_bc.bc") is None
    True
    """
    if old in MOVED:
        return MOVED[old]
    head, _, tail = old.rpartition(".")
    while head:
        if head in MOVED:
            return MOVED[head] + "." + tail
        head, _, rest = head.rpartition(".")
        tail = rest + "." + tail
    return None


class _Alias(importlib.abc.Loader):
    def __init__(self, old: str, new: str) -> None:
        self.old, self.new = old, new

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> Any:
        _warn(self.old, self.new)
        module = importlib.import_module(self.new)
        self._spec = module.__spec__
        return module

    def exec_module(self, module: Any) -> None:
        module.__spec__ = self._spec  # the import system stamped the old name on it


class _Finder(importlib.abc.MetaPathFinder):
    def find_spec(self, name: str, path: Any = None, target: Any = None) -> Any:
        new = new_name(name) if name.startswith("safe_bc.") else None
        if new is None:
            return None
        return importlib.machinery.ModuleSpec(name, _Alias(name, new))


def install() -> None:
    """Answer old module names (idempotent)."""
    if not any(isinstance(f, _Finder) for f in sys.meta_path):
        sys.meta_path.insert(0, _Finder())


def forward(package: str, home: str) -> Callable[[str], Any]:
    """A module ``__getattr__`` for ``package``: an old name is read from ``home`` (warning
    once); anything else is no attribute (so a submodule imports as usual)."""

    def __getattr__(name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        module = importlib.import_module(home)
        if not hasattr(module, name):
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        _warn(f"{package}.{name}", f"{home}.{name}")
        return getattr(module, name)

    return __getattr__


def names(module: str) -> Callable[[str], Any]:
    """A module ``__getattr__`` for ``module``: its old names of :data:`NAMES` are read from
    their new home (warning once); anything else is no attribute."""

    def __getattr__(name: str) -> Any:
        new = NAMES.get(f"{module}.{name}")
        if new is None:
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        home, _, attr = new.rpartition(".")
        _warn(f"{module}.{name}", new)
        return getattr(importlib.import_module(home), attr)

    return __getattr__
