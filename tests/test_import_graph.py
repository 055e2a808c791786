"""safe_bc's import graph: no cycle, no import up a layer, and every module imports on its own.

The graph comes from the source (``ast``): an edge ``A -> B`` for every ``import B`` /
``from B import x`` anywhere in ``A``, at module level or inside a function (``from P import
m`` also counts ``P.m`` when it is a module). A function-local import runs later, but it is a
dependency all the same: the checks read both kinds, so a local import cannot hide a cycle or
a climb. Imports under ``if TYPE_CHECKING:`` never run and are left out.

The layers, bottom to top, are those of ``docs/design.md`` (:data:`LAYERS`): a module may
import its own layer and those below it, never one above.
"""

from __future__ import annotations

import ast
import fnmatch
import itertools
import re
import subprocess
import sys
import textwrap
from collections.abc import Callable
from pathlib import Path

import pytest

import safe_bc

ROOT = Path(safe_bc.__file__).resolve().parent
DESIGN = ROOT.parent / "docs" / "design.md"

LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    (
        "core",
        (
            "safe_bc.version", "safe_bc.moved", "safe_bc.selection", "safe_bc.report",
            "safe_bc.handover", "safe_bc.seeds", "safe_bc.policy", "safe_bc.progress",
            "safe_bc.overrides", "safe_bc.config_file",
        ),
    ),
    ("data", ("safe_bc.data", "safe_bc.data.*", "safe_bc.metrics", "safe_bc.plots")),
    ("bc", ("safe_bc.bc", "safe_bc.bc.*", "safe_bc.run_config")),
    ("tasks", ("safe_bc.tasks", "safe_bc.tasks.*")),
    ("rollout", ("safe_bc.rollout", "safe_bc.rollout.*", "safe_bc.export", "safe_bc.export.*")),
    ("methods", ("safe_bc.methods", "safe_bc.methods.*")),
    ("distributed", ("safe_bc.distributed", "safe_bc.distributed.*")),
    ("study", ("safe_bc.study", "safe_bc.study.*")),
    ("compare", ("safe_bc.compare", "safe_bc.compare.*")),
    ("peers", ("safe_bc.peers", "safe_bc.peers.*")),
    ("entry", ("safe_bc", "safe_bc.cli", "safe_bc.cli.*", "safe_bc.render",
               "safe_bc.peers.run", "safe_bc.peers.__main__")),
)  # fmt: skip
"""Layer name -> module patterns (``fnmatch``), bottom to top: the feature packages of
``docs/design.md``. A module is in the layer of its longest matching pattern."""

PURE: tuple[str, ...] = (
    "safe_bc.version", "safe_bc.moved", "safe_bc.selection", "safe_bc.metrics",
    "safe_bc.report", "safe_bc.handover", "safe_bc.seeds", "safe_bc.policy",
    "safe_bc.run_config", "safe_bc.data.codec", "safe_bc.data.episode", "safe_bc.data.demos",
    "safe_bc.tasks.env_config", "safe_bc.*.config", "safe_bc.*.logic", "safe_bc.methods",
    "safe_bc.methods.registry", "safe_bc.methods.layout", "safe_bc.compare.rows",
    "safe_bc.methods.selfimprove.choice",
)  # fmt: skip
"""Pure logic and configs, free of I/O, Ray and torch (checked per file, whatever its
folder): such a module imports only pure modules, at module level or inside a function."""

PURE_READS: dict[tuple[str, str], str] = {
    ("safe_bc.methods.selfimprove.config", "safe_bc.tasks.registry"):
        "a method reads its per-task defaults from the task's record, when asked",
}  # fmt: skip
"""Imports of a pure module that are not pure, with the reason (each inside a function)."""

RAY: tuple[str, ...] = ("safe_bc.distributed.*", "safe_bc.study.*")
"""Where ``ray`` may be imported: the modules that run work on it (checked per file)."""


def module_names() -> dict[str, Path]:
    """``{"safe_bc.bc.net": path, "safe_bc.bc": .../bc/__init__.py, ...}``."""
    out = {}
    for path in sorted(ROOT.rglob("*.py")):
        parts = ["safe_bc", *path.relative_to(ROOT).with_suffix("").parts]
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _imports(name: str, path: Path, modules: dict[str, Path]) -> tuple[set[str], dict[str, int]]:
    """``(module-level targets, {function-local target: line})`` among ``modules``."""
    is_pkg = path.name == "__init__.py"
    package = name if is_pkg else name.rpartition(".")[0]
    top: set[str] = set()
    local: dict[str, int] = {}

    def targets(node: ast.Import | ast.ImportFrom) -> set[str]:
        found: set[str] = set()
        if isinstance(node, ast.Import):
            for alias in node.names:
                # ``import a.b.c`` runs a, a.b and a.b.c; the parents are the caller's packages
                # or re-exporting __init__s, so only the named module counts.
                found.add(alias.name)
        else:
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join([*anchor, base] if base else anchor)
            found.add(base)
            found.update(f"{base}.{alias.name}" for alias in node.names)
        return {t for t in found if t in modules and t != name}

    def visit(node: ast.AST, in_function: bool) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            for child in node.orelse:
                visit(child, in_function)
            return
        if isinstance(node, ast.Import | ast.ImportFrom):
            for target in targets(node):
                if in_function:
                    local.setdefault(target, node.lineno)
                else:
                    top.add(target)
            return
        inner = in_function or isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda)
        for child in ast.iter_child_nodes(node):
            visit(child, inner)

    visit(ast.parse(path.read_text(), filename=str(path)), False)
    return top, local


def graph() -> tuple[dict[str, set[str]], dict[str, dict[str, int]]]:
    modules = module_names()
    top, local = {}, {}
    for name, path in modules.items():
        top[name], local[name] = _imports(name, path, modules)
    return top, local


def edges() -> tuple[dict[str, set[str]], dict[tuple[str, str], str]]:
    """Every edge, module-level or function-local, and where it is (``"a.py:12"`` for local
    ones, ``"module level"`` otherwise)."""
    top, local = graph()
    where = {(a, b): "module level" for a, targets in top.items() for b in targets}
    for a, targets in local.items():
        for b, line in targets.items():
            where.setdefault((a, b), f"line {line}")
    full = {a: top[a] | set(local[a]) for a in top}
    return full, where


def layer_of(name: str) -> str:
    """The layer of module ``name`` (see :data:`LAYERS`)."""
    matches = [(len(p), layer) for layer, patterns in LAYERS for p in patterns
               if fnmatch.fnmatchcase(name, p)]  # fmt: skip
    if not matches:
        raise ValueError(f"{name} is in no layer")
    return max(matches)[1]


def upward_imports(full: dict[str, set[str]], layer: Callable[[str], str]) -> list[tuple[str, str]]:
    """Edges ``(a, b)`` where ``b``'s layer lies above ``a``'s."""
    rank = {name: i for i, (name, _) in enumerate(LAYERS)}
    return [(a, b) for a in sorted(full) for b in sorted(full[a])
            if rank[layer(b)] > rank[layer(a)]]  # fmt: skip


def _reach(top: dict[str, set[str]], start: str) -> dict[str, str | None]:
    """Every module reachable from ``start`` at module level, with its predecessor."""
    prev: dict[str, str | None] = {start: None}
    todo = [start]
    while todo:
        node = todo.pop()
        for nxt in sorted(top[node]):
            if nxt not in prev:
                prev[nxt] = node
                todo.append(nxt)
    return prev


def _path(prev: dict[str, str | None], end: str) -> list[str]:
    out = [end]
    while (p := prev[out[-1]]) is not None:
        out.append(p)
    return out[::-1]


def module_cycles(top: dict[str, set[str]]) -> list[list[str]]:
    """One cycle per module that lies on one, e.g. ``[a, b, a]``."""
    cycles = []
    for name in sorted(top):
        for nxt in sorted(top[name]):
            prev = _reach(top, nxt)
            if name in prev:
                cycles.append([name, *_path(prev, name)])
                break
    return cycles


def test_graph_sees_the_package():
    top, _ = graph()
    assert "safe_bc.bc.config" in top["safe_bc.bc"]  # the rest of bc loads lazily (PEP 562)
    assert "safe_bc.bc.net" in top["safe_bc.bc.checkpoint"]
    assert len(top) > 30


def test_no_import_cycle():
    """Module-level and function-local imports together form no cycle."""
    full, where = edges()
    cycles = module_cycles(full)
    assert cycles == [], [
        " -> ".join(c) + " (" + ", ".join(where[e] for e in itertools.pairwise(c)) + ")"
        for c in cycles
    ]


def test_the_collection_and_the_task_registry_are_not_a_cycle():
    """The cycle once hidden by function-local imports: collection -> envs.factory ->
    tasks.carracing -> tasks.registry -> collection."""
    full, _ = edges()
    assert "safe_bc.tasks.registry" in _reach(full, "safe_bc.rollout.collect")
    assert "safe_bc.rollout.collect" not in _reach(full, "safe_bc.tasks.registry")


def test_no_task_writes_into_a_method():
    """A method reads its per-task defaults from the task's record; the registry names none."""
    full, _ = edges()
    assert not any(m.startswith("safe_bc.methods") for m in _reach(full, "safe_bc.tasks"))


def is_pure(name: str) -> bool:
    return any(fnmatch.fnmatchcase(name, p) for p in PURE)


def test_pure_modules_import_only_pure_ones():
    """The per-file rule: pure logic is free of I/O and Ray whatever folder it sits in."""
    full, where = edges()
    bad = [f"{a} imports {b} ({where[a, b]})" for a in sorted(full) if is_pure(a)
           for b in sorted(full[a]) if not is_pure(b) and (a, b) not in PURE_READS]  # fmt: skip
    assert bad == []
    assert all(where[k] != "module level" for k in PURE_READS)


def _third_party(path: Path) -> set[str]:
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            found.add(node.module.split(".")[0])
    return found


def test_ray_only_where_it_runs_work():
    users = [n for n, p in module_names().items() if "ray" in _third_party(p)]
    assert users and all(any(fnmatch.fnmatchcase(n, p) for p in RAY) for n in users), users
    assert not [n for n, p in module_names().items() if is_pure(n) and
                {"ray", "torch", "pyarrow"} & _third_party(p)]  # fmt: skip


def test_every_module_has_a_layer():
    for name in module_names():
        assert layer_of(name) in dict(LAYERS)
    assert layer_of("safe_bc.study.run") == "study"
    assert layer_of("safe_bc.bc.config") == "bc" and is_pure("safe_bc.bc.config")
    assert not is_pure("safe_bc.bc.net")
    assert layer_of("safe_bc") == "entry" and layer_of("safe_bc.data.store") == "data"
    assert layer_of("safe_bc.tasks.carracing.costs") == "tasks"


def test_no_import_climbs_a_layer():
    full, where = edges()
    up = upward_imports(full, layer_of)
    assert up == [], [
        f"{a} ({layer_of(a)}) imports {b} ({layer_of(b)}), {where[a, b]}" for a, b in up
    ]


def test_the_design_page_names_the_layers_in_order():
    """docs/design.md's layer list and :data:`LAYERS` are one order."""
    section = DESIGN.read_text().split("## Layers", 1)[1].split("\n## ", 1)[0]
    named = re.findall(r"^\d+\. \*\*(\w+)\*\*", section, flags=re.M)
    assert named == [name for name, _ in LAYERS]


def test_the_checks_catch_cycles_and_climbs():
    top = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}
    assert module_cycles(top)[0] == ["a", "b", "c", "a"]
    top = {"a": {"b"}, "b": {"c"}, "c": set()}
    assert module_cycles(top) == []
    layers = {"a": "entry", "b": "methods", "c": "core"}
    assert upward_imports(top, layers.__getitem__) == []
    top["c"].add("a")
    assert upward_imports(top, layers.__getitem__) == [("c", "a")]


def test_imports_parse(tmp_path):
    pkg = tmp_path / "safe_bc"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "sub" / "__init__.py").write_text("from safe_bc.sub.x import f\n")
    (pkg / "sub" / "x.py").write_text(
        textwrap.dedent(
            """
            from typing import TYPE_CHECKING
            from . import y
            if TYPE_CHECKING:
                from safe_bc.sub import z
            def f():
                import safe_bc.sub
            """
        )
    )
    modules = {"safe_bc.sub": pkg / "sub" / "__init__.py", "safe_bc.sub.x": pkg / "sub" / "x.py"}
    modules |= {"safe_bc.sub.y": pkg / "y.py", "safe_bc.sub.z": pkg / "z.py"}
    top, local = _imports("safe_bc.sub.x", modules["safe_bc.sub.x"], modules)
    assert top == {"safe_bc.sub", "safe_bc.sub.y"}
    assert local == {"safe_bc.sub": 7}


@pytest.mark.timeout(300)
def test_every_module_imports_first():
    """Each module imported first, with no other safe_bc module loaded (one interpreter, the
    ``safe_bc`` entries of ``sys.modules`` cleared between modules; third-party ones stay)."""
    names = sorted(module_names())
    code = textwrap.dedent(
        f"""
        import importlib, sys, traceback, warnings
        warnings.simplefilter("ignore")
        failed = []
        for name in {names!r}:
            for key in [k for k in sys.modules if k == "safe_bc" or k.startswith("safe_bc.")]:
                del sys.modules[key]
            try:
                importlib.import_module(name)
            except BaseException:
                failed.append(name + ": " + traceback.format_exc(limit=-3))
        print("\\n".join(failed))
        sys.exit(1 if failed else 0)
        """
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=280)
    assert proc.returncode == 0, proc.stdout + proc.stderr[-3000:]
