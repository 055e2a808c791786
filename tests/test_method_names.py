"""The study, comparison and command-line packages name no built-in method: they read the
method registry (:data:`safe_bc.methods.METHODS`), so that a method added through it is served
like the built-in ones (one way in for a method).

A *mention* is a built-in method's registered name (``improve``, ``queries``, ``selfimprove``)
in the code of ``safe_bc/study/``, ``safe_bc/compare/`` or ``safe_bc/cli/``: an identifier
(``spec.selfimprove``, ``def improve``, a keyword), a module path
(``from safe_bc.methods.selfimprove...``) or a word of a string literal (``"selfimprove"``);
docstrings and comments are prose and are not read. :data:`ALLOWED` lists the mentions left,
each line with its reason; a new one fails :func:`test_no_new_mention_of_a_built_in_method`, and
an entry whose line no longer mentions a method fails
:func:`test_every_allowed_mention_is_still_there` (remove it: the list only shrinks).
"""

from __future__ import annotations

import ast
import re
from collections.abc import Iterator
from pathlib import Path

import safe_bc

ROOT = Path(safe_bc.__file__).resolve().parent
FOLDERS = ("study", "compare", "cli")
BUILT_IN = ("improve", "queries", "selfimprove")
_WORD = re.compile(r"\b(" + "|".join(BUILT_IN) + r")\b")

IDENTITY = "a StudySpec field named after a method: part of every committed study's identity"

ALLOWED: dict[tuple[str, str], str] = {
    ("study/spec.py", "from safe_bc.methods.improve.config import ImproveConfig"): IDENTITY,
    ("study/spec.py", "from safe_bc.methods.queries.config import QueryConfig"): IDENTITY,
    ("study/spec.py", "from safe_bc.methods.selfimprove.config import SelfImproveConfig"):
        IDENTITY,
    ("study/spec.py", "improve: ImproveConfig | None = None"): IDENTITY,
    ("study/spec.py", "queries: QueryConfig | None = None"): IDENTITY,
    ("study/spec.py", "selfimprove: SelfImproveConfig | None = None"): IDENTITY,
}  # fmt: skip
"""(file below ``safe_bc/``, its stripped source line) -> why that line may mention a built-in
method."""


def _docstrings(tree: ast.AST) -> set[int]:
    """``id`` of every docstring (a module's, class's, function's, or an attribute's: the
    string right below an assignment)."""
    out = set()
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if not isinstance(body, list):
            continue
        for i, st in enumerate(body):
            first = i == 0 and isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef)
            below = i > 0 and isinstance(body[i - 1], ast.Assign | ast.AnnAssign)
            if (first or below) and isinstance(st, ast.Expr) and isinstance(st.value, ast.Constant):
                out.add(id(st.value))
    return out


def _words(node: ast.AST, prose: set[int]) -> list[str]:
    if isinstance(node, ast.Name):
        return [node.id]
    if isinstance(node, ast.Attribute):
        return [node.attr]
    if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
        return [node.name]
    if isinstance(node, ast.arg):
        return [node.arg]
    if isinstance(node, ast.keyword):
        return [node.arg or ""]
    if isinstance(node, ast.alias):
        return [*node.name.split("."), node.asname or ""]
    if isinstance(node, ast.ImportFrom):
        return (node.module or "").split(".")
    if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in prose:
        return _WORD.findall(node.value)
    return []


def mentions() -> Iterator[tuple[str, str, str]]:
    """``(file below safe_bc/, stripped line, method name)`` of every mention."""
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            text = path.read_text()
            lines, tree = text.splitlines(), ast.parse(text)
            prose = _docstrings(tree)
            for node in ast.walk(tree):
                for word in _words(node, prose):
                    if word in BUILT_IN:
                        line = lines[node.lineno - 1].strip()  # type: ignore[attr-defined]
                        yield path.relative_to(ROOT).as_posix(), line, word


def test_no_new_mention_of_a_built_in_method() -> None:
    new = sorted({(f, line, w) for f, line, w in mentions() if (f, line) not in ALLOWED})
    assert not new, (
        "built-in method named in study/compare/cli code (read it through safe_bc.methods."
        "METHODS / method_of / method_of_config, or add it to ALLOWED with its reason):\n"
        + "\n".join(f"safe_bc/{f}: {w}: {line}" for f, line, w in new)
    )


def test_every_allowed_mention_is_still_there() -> None:
    found = {(f, line) for f, line, _ in mentions()}
    assert not sorted(set(ALLOWED) - found), "mentions gone: remove them from ALLOWED"


def test_the_check_sees_identifiers_paths_and_strings_not_prose(tmp_path: Path) -> None:
    code = '''"""A docstring on improve."""
from safe_bc.methods.selfimprove import x  # a comment on queries
y = spec.queries
z = "improve"
w = "improved things"
'''
    tree = ast.parse(code)
    prose = _docstrings(tree)
    found = sorted({w for n in ast.walk(tree) for w in _words(n, prose) if w in BUILT_IN})
    assert found == ["improve", "queries", "selfimprove"]
