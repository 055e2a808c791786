"""Attribute docstrings of the frozen config dataclasses, read from their source (no import).

The CLI's help text for an option that sets a config field is that field's docstring, so a
default and its explanation live once, beside the field (as tyro does for ``tyro.cli``).
Reading the source with :mod:`ast` instead of importing keeps ``safe-bc --help`` free of
torch.
"""

from __future__ import annotations

import ast
import functools
import importlib.util
import itertools
import re
from pathlib import Path


@functools.cache
def _class_docs(module: str, cls: str) -> dict[str, str]:
    spec = importlib.util.find_spec(module)
    if spec is None or spec.origin is None:
        raise LookupError(f"module {module} not found")
    tree = ast.parse(Path(spec.origin).read_text())
    for node in tree.body:
        if isinstance(node, ast.ClassDef) and node.name == cls:
            docs, body = {}, node.body
            for field, doc in itertools.pairwise(body):
                if (
                    isinstance(field, ast.AnnAssign)
                    and isinstance(field.target, ast.Name)
                    and isinstance(doc, ast.Expr)
                    and isinstance(doc.value, ast.Constant)
                    and isinstance(doc.value.value, str)
                ):
                    docs[field.target.id] = doc.value.value
            return docs
    raise LookupError(f"class {cls} not found in {module}")


def field_doc(module: str, cls: str, field: str) -> str:
    """The first sentence of ``module.cls.field``'s attribute docstring, on one line, with
    reST markup (double backticks) dropped; ``LookupError`` when it has none."""
    docs = _class_docs(module, cls)
    if field not in docs:
        raise LookupError(f"{module}.{cls}.{field} has no docstring")
    text = " ".join(docs[field].split()).replace("``", "")
    first = re.split(r"(?<=[a-z)\]]\.)\s+(?=[A-Z0-9(])", text, maxsplit=1)[0]
    return first.rstrip(".").replace("%", "%%")  # argparse formats help with %
