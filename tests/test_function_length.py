"""No function in ``safe_bc/`` over :data:`MAX_LINES` lines, but the few still listed in
:data:`LONG`, and that list only shrinks: a listed function that got shorter (or went away)
must leave it, and a new long one fails."""

from __future__ import annotations

import ast
from pathlib import Path

import safe_bc

ROOT = Path(safe_bc.__file__).resolve().parent
MAX_LINES = 100
"""A function's lines from its ``def`` to its last line, docstring and comments included."""

LONG: dict[str, int] = {}
"""The functions still over the limit, with their length today (none may grow)."""


def function_lengths(root: Path) -> dict[str, int]:
    """``{"path:Class.function": lines}`` for every function and method under ``root``."""
    out: dict[str, int] = {}

    def walk(node: ast.AST, where: str, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
                name = f"{prefix}{child.name}"
                out[f"{where}:{name}"] = child.end_lineno - child.lineno + 1
                walk(child, where, f"{name}.")
            elif isinstance(child, ast.ClassDef):
                walk(child, where, f"{prefix}{child.name}.")
            else:
                walk(child, where, prefix)

    for path in sorted(root.rglob("*.py")):
        walk(ast.parse(path.read_text(), filename=str(path)), path.relative_to(root).as_posix(), "")
    return out


def test_no_new_function_over_the_limit_and_none_listed_grows():
    lengths = function_lengths(ROOT)
    over = {name: n for name, n in lengths.items() if n > MAX_LINES}
    new = sorted(set(over) - set(LONG))
    assert not new, f"over {MAX_LINES} lines (split them): " + ", ".join(
        f"{k} ({over[k]})" for k in new
    )
    grown = [f"{k}: {lengths[k]} > {LONG[k]}" for k in LONG if k in over and over[k] > LONG[k]]
    assert not grown, grown


def test_the_list_only_shrinks():
    """A listed function now within the limit (or gone) leaves :data:`LONG`."""
    lengths = function_lengths(ROOT)
    done = sorted(k for k in LONG if lengths.get(k, 0) <= MAX_LINES)
    assert not done, f"within {MAX_LINES} lines now, drop from LONG: {done}"


def test_lengths_are_counted_from_def_to_last_line(tmp_path):
    (tmp_path / "m.py").write_text(
        "class A:\n    def f(self):\n        def g():\n            pass\n        return 1\n"
    )
    assert function_lengths(tmp_path) == {"m.py:A.f": 4, "m.py:A.f.g": 2}
