"""The short help of a ``safe-bc`` command: one line per flag (wrapped where a line would not
fit), with the first sentence of its field's docstring, RST markup removed.

Built from the command's record (:mod:`safe_bc.cli.jobs`) without tyro, so ``--help`` imports
neither tyro's parser nor torch or Ray. The flags are tyro's (dotted names of nested configs,
``--x / --no-x`` for booleans, fields marked ``Flat`` without their own prefix, positional
fields as ``STUDY``); ``--help-full`` prints tyro's own help with the whole docstrings.
"""

from __future__ import annotations

import ast
import dataclasses
import functools
import inspect
import re
import textwrap
import types
import typing
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

NAME_WIDTH = 34
"""Column where a flag's help starts (a longer flag puts its help on the next line)."""


@dataclass(frozen=True)
class Flag:
    """One command-line flag of a record's field."""

    name: str
    """``--selection.eps``, ``--quiet / --no-quiet`` or a positional's ``STUDY``."""
    meta: str
    """What it takes: ``FLOAT``, ``{max,quantile}``, ``PATH|None``; empty for a boolean."""
    default: str | None
    """The default as shown; ``None``: required."""
    help: str
    """The first sentence of the field's docstring."""
    group: str
    """The dotted prefix of a nested config's flags (empty at the top)."""


def plain(text: str) -> str:
    """``text`` without RST markup (``:class:`X```, ````x````, ```x```) on one line."""
    text = re.sub(r":[a-z]+:`~?([^`]+)`", r"\1", text)
    text = text.replace("``", "").replace("`", "")
    return " ".join(text.split())


def first_sentence(text: str) -> str:
    """The first sentence of a docstring (up to a full stop followed by a capital letter, a
    blank line or the end), as plain text.

    >>> first_sentence("Width of the edge, e.g. 2 px. The default ``2`` puts ...")
    'Width of the edge, e.g. 2 px.'
    """
    para = re.split(r"\n\s*\n", text.strip(), maxsplit=1)[0]
    para = plain(para)
    found = re.search(r"[.!?](?=\s+[A-Z(\"'])", para)
    return para[: found.end()] if found else para


@functools.cache
def field_docs(cls: type) -> dict[str, str]:
    """``{field: docstring}`` of a dataclass and its bases: the string literal under each
    annotated field (attribute docstrings, as tyro reads them)."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if klass is object or not dataclasses.is_dataclass(klass):
            continue
        try:
            tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
        except (OSError, TypeError):
            continue
        body = tree.body[0].body if tree.body and isinstance(tree.body[0], ast.ClassDef) else []
        for node, after in zip(body, [*body[1:], None], strict=True):
            if (
                isinstance(node, ast.AnnAssign)
                and isinstance(node.target, ast.Name)
                and isinstance(after, ast.Expr)
                and isinstance(after.value, ast.Constant)
                and isinstance(after.value.value, str)
            ):
                docs[node.target.id] = inspect.cleandoc(after.value.value)
    return docs


def _markers(hint: Any) -> tuple[Any, tuple[Any, ...]]:
    """``(the type, its Annotated extras)``."""
    if typing.get_origin(hint) is typing.Annotated:
        kind, *extras = typing.get_args(hint)
        return kind, tuple(extras)
    return hint, ()


def _marker(alias: Any) -> Any:
    """The marker object of a tyro ``Annotated`` alias (``tyro.conf.Positional``)."""
    return typing.get_args(alias[int])[1]


def _meta(kind: Any) -> str:
    """tyro-like metavar of a type: ``INT``, ``{a,b}``, ``[FLOAT ...]``, ``PATH|None``."""
    origin, args = typing.get_origin(kind), typing.get_args(kind)
    if origin is typing.Literal:
        return "{" + ",".join(str(a) for a in args) + "}"
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in args if a is not type(None)]
        shown = "|".join(_meta(a) for a in inner)
        return f"{shown}|None" if len(inner) < len(args) else shown
    if origin in (tuple, list, set, frozenset):
        return f"[{_meta(args[0]) if args else 'STR'} ...]"
    if kind is Path or (isinstance(kind, type) and issubclass(kind, Path)):
        return "PATH"
    if isinstance(kind, type):
        return kind.__name__.upper()
    return str(kind).upper()


def _shown(value: Any) -> str:
    if isinstance(value, tuple | list):
        return " ".join(str(v) for v in value) or "()"
    return str(value)


def _is_dataclass_type(kind: Any) -> bool:
    return isinstance(kind, type) and dataclasses.is_dataclass(kind)


def _optional_dataclass(kind: Any) -> bool:
    """``SomeConfig | None``: a nested config that may be left out."""
    args = typing.get_args(kind)
    return type(None) in args and any(_is_dataclass_type(a) for a in args)


def flags(cls: type, prefix: str = "", default: Any = None) -> Iterator[Flag]:
    """The flags of record ``cls`` (its nested configs' too), in field order."""
    import tyro

    flat = tyro.conf.arg(name="")
    suppressed = {_marker(tyro.conf.Suppress), _marker(tyro.conf.SuppressFixed)}
    positional_marker = _marker(tyro.conf.Positional)
    hints = typing.get_type_hints(cls, include_extras=True)
    docs = field_docs(cls)
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        kind, extras = _markers(hints[f.name])
        if any(any(e is m for m in suppressed) for e in extras):
            continue
        if _optional_dataclass(kind):  # tyro offers it as a choice of subcommands, no flag
            continue
        if default is not None:
            value = getattr(default, f.name)
        elif f.default is not dataclasses.MISSING:
            value = f.default
        elif f.default_factory is not dataclasses.MISSING:
            value = f.default_factory()
        else:
            value = dataclasses.MISSING
        if _is_dataclass_type(kind):
            inner = prefix if flat in extras else f"{prefix}{f.name}."
            yield from flags(kind, inner, None if value is dataclasses.MISSING else value)
            continue
        positional = any(e is positional_marker for e in extras)
        dashed = f.name.replace("_", "-")
        help_text = first_sentence(docs.get(f.name, ""))
        shown = None if value is dataclasses.MISSING else _shown(value)
        group = prefix.rstrip(".")
        if positional:
            yield Flag(f.name.upper(), _meta(kind), shown, help_text, group)
        elif kind is bool:
            name = f"--{prefix}{dashed} / --{prefix}no-{dashed}"
            yield Flag(name, "", shown, help_text, group)
        else:
            yield Flag(f"--{prefix}{dashed}", _meta(kind), shown, help_text, group)


def _group_docs(cls: type, prefix: str = "") -> dict[str, str]:
    """``{dotted prefix: first sentence of the nested config field's docstring}`` (else of
    the nested config's class docstring)."""
    import tyro

    flat = tyro.conf.arg(name="")
    out: dict[str, str] = {}
    hints = typing.get_type_hints(cls, include_extras=True)
    docs = field_docs(cls)
    for f in dataclasses.fields(cls):
        kind, extras = _markers(hints[f.name])
        if _is_dataclass_type(kind):
            inner = prefix if flat in extras else f"{prefix}{f.name}."
            if inner != prefix:
                about = docs.get(f.name) or inspect.getdoc(kind) or ""
                out[inner.rstrip(".")] = first_sentence(about)
            out.update(_group_docs(kind, inner))
    return out


def _entry(flag: Flag, width: int, most: int) -> list[str]:
    """``flag``'s lines: name, what it takes and its default, then its help from column
    :data:`NAME_WIDTH`, wrapped to ``width`` in at most ``most`` lines (the last one cut with
    an ellipsis when the sentence is longer)."""
    shown = "required" if flag.default is None else flag.default
    left = f"  {flag.name} {flag.meta}".rstrip() + f" [{shown}]"
    pad = " " * NAME_WIDTH
    first = left.ljust(NAME_WIDTH) if len(left) < NAME_WIDTH else left + "  "
    if len(first) > width - 16:  # too little room: the help starts on the next line
        lines = [left, *textwrap.wrap(flag.help, width, initial_indent=pad, subsequent_indent=pad)]
    else:
        lines = textwrap.wrap(flag.help or "-", width, initial_indent=first,
                              subsequent_indent=pad) or [first.rstrip()]  # fmt: skip
    if len(lines) > most:
        lines = lines[:most]
        lines[-1] = lines[-1][: width - 1].rstrip() + "…"
    return lines


def render(cls: type, prog: str, about: str, width: int = 100, max_lines: int = 79) -> str:
    """The short help of record ``cls`` as ``prog``'s: usage, ``about`` (its first paragraph
    and a paragraph of lines ``Alias --x for --y.``), then the flags by group, one entry
    each; entries are cut (with an ellipsis) to as many lines each as keep the whole help
    within ``max_lines`` where the flags allow it."""
    all_flags = list(flags(cls))
    positional = [f.name for f in all_flags if not f.name.startswith("-")]
    required = [f"{f.name} {f.meta}" for f in all_flags if f.default is None and f.meta]
    usage = " ".join([f"usage: {prog}", *positional, *[r for r in required if r[0] == "-"]])
    head = [usage + " [OPTIONS]", ""]
    paragraphs = [p for p in re.split(r"\n\s*\n", inspect.cleandoc(about)) if p.strip()]
    head += textwrap.wrap(plain(paragraphs[0]) if paragraphs else "", width)
    head += [plain(a) for p in paragraphs[1:] if p.startswith("Alias ") for a in p.splitlines()]
    tail = ["", f"Every field's whole docstring: {prog} --help-full"]
    groups = _group_docs(cls)

    def body(most: int) -> list[str]:
        lines: list[str] = []
        current = None
        for f in all_flags:
            if f.group != current:
                current = f.group
                title = f"{f.group}: {groups.get(f.group, '')}".rstrip() if f.group else "options:"
                if len(title) > width:
                    title = title[: width - 1].rstrip() + "…"
                lines += [title]
            lines += _entry(f, width, most)
        return lines

    most = 4
    lines = body(most)
    while most > 1 and len(head) + 1 + len(lines) + len(tail) > max_lines:
        most -= 1
        lines = body(most)
    return "\n".join([*head, "", *lines, *tail])
