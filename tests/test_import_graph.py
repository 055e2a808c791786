"""No import cycles among safe_bc's modules, and every module imports on its own.

The graph comes from the source (``ast``): an edge ``A -> B`` for every ``import B`` /
``from B import x`` in ``A`` (``from P import m`` also counts ``P.m`` when it is a module).
Module-level imports must form no cycle. A function-local import must not reach back: a
module may import ``B`` inside a function only if ``B`` does not (transitively, at module
level) import the module itself; otherwise the local import just hides a cycle.
Imports under ``if TYPE_CHECKING:`` never run and are left out.
"""

from __future__ import annotations

import ast
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

import safe_bc

ROOT = Path(safe_bc.__file__).resolve().parent


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


def hidden_cycles(top: dict[str, set[str]], local: dict[str, dict[str, int]]) -> list[str]:
    """Function-local imports of a module that imports the importer back."""
    found = []
    for name in sorted(local):
        for target, line in sorted(local[name].items()):
            prev = _reach(top, target)
            if name in prev:
                chain = " -> ".join(_path(prev, name))
                found.append(f"{name}:{line} imports {target} locally, but {chain}")
    return found


def test_graph_sees_the_package():
    top, _ = graph()
    assert "safe_bc.bc.config" in top["safe_bc.bc"]  # the rest of bc loads lazily (PEP 562)
    assert "safe_bc.bc.net" in top["safe_bc.bc.checkpoint"]
    assert len(top) > 30


def test_no_module_level_import_cycle():
    top, _ = graph()
    assert module_cycles(top) == []


def test_no_function_local_import_hides_a_cycle():
    top, local = graph()
    assert hidden_cycles(top, local) == []


def test_the_checks_catch_cycles():
    top = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}
    assert module_cycles(top)[0] == ["a", "b", "c", "a"]
    top = {"a": {"b"}, "b": {"c"}, "c": set()}
    assert module_cycles(top) == []
    (hidden,) = hidden_cycles(top, {"c": {"a": 7}, "a": {}, "b": {}})
    assert hidden == "c:7 imports a locally, but a -> b -> c"


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
