"""``FIELD=VALUE`` overrides of a frozen config (``safe-bc tune --set batches=500
env.max_episode_steps=300 base.bc.train.lr=1e-3``), checked against its dataclass fields.

:func:`parse_override` turns one string into ``(path, value)`` with the value converted to the
field's type; :func:`apply_overrides` replaces the fields (the configs' ``__post_init__``
checks then run). A nested config is set field by field; one that is ``None`` is built from
its defaults first. Pure: no I/O.
"""

from __future__ import annotations

import dataclasses
import difflib
import types
import typing
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

Whole = Mapping[type, Callable[[str], Any]]
"""Config types that one string sets whole (``env=rehab``: the task's env), by their type."""

_NONE = ("None", "none", "null")
_TRUE, _FALSE = ("true", "yes", "1", "on"), ("false", "no", "0", "off")


def _hints(cls: type) -> dict[str, Any]:
    hints = typing.get_type_hints(cls)
    return {f.name: hints[f.name] for f in dataclasses.fields(cls) if f.init}


def _strip(kind: Any) -> tuple[Any, bool]:
    """``(the type without None, whether None is allowed)``."""
    origin, args = typing.get_origin(kind), typing.get_args(kind)
    if origin in (typing.Union, types.UnionType) and type(None) in args:
        inner = tuple(a for a in args if a is not type(None))
        return (inner[0] if len(inner) == 1 else typing.Union[inner]), True  # noqa: UP007
    return kind, False


def _config_type(kind: Any) -> type | None:
    """The config (dataclass) type of a field: the type itself, or the one config among the
    options of a union (``HandoverConfig | Literal["task"] | None``)."""
    inner, _ = _strip(kind)
    options = (
        typing.get_args(inner)
        if typing.get_origin(inner) in (typing.Union, types.UnionType)
        else (inner,)
    )
    configs = [t for t in options if isinstance(t, type) and dataclasses.is_dataclass(t)]
    return configs[0] if len(configs) == 1 else None


def resolve(cls: type, path: str) -> Any:
    """The type of the field at dotted ``path`` of dataclass ``cls``.

    Raises:
        ValueError: a name that is no field (with the closest names).
    """
    kind: Any = cls
    for depth, name in enumerate(path.split(".")):
        config = _config_type(kind)
        if config is None:
            where = ".".join(path.split(".")[:depth])
            raise ValueError(f"{where} is not a config with fields")
        fields = _hints(config)
        if name not in fields:
            near = difflib.get_close_matches(name, fields, n=3)
            hint = f" (did you mean {', '.join(near)}?)" if near else ""
            raise ValueError(f"{config.__name__} has no field {name!r}{hint}")
        kind = fields[name]
    return kind


def convert(kind: Any, text: str, whole: Whole | None = None) -> Any:
    """``text`` as a value of type ``kind`` (int, float, bool, str, Path, Literal, tuples as
    comma-separated items, ``None`` where allowed, a config in ``whole``).

    Raises:
        ValueError: ``text`` is not such a value.
    """
    inner, optional = _strip(kind)
    if optional and text in _NONE:
        return None
    for config, build in (whole or {}).items():
        if inner is config:
            return build(text)
    if isinstance(inner, type) and dataclasses.is_dataclass(inner):
        raise ValueError(f"a config: set its fields (FIELD.NAME=VALUE), not {text!r}")
    origin, args = typing.get_origin(inner), typing.get_args(inner)
    if origin is typing.Literal:
        for option in args:
            if str(option) == text:
                return option
        raise ValueError(f"{text!r} is not one of {', '.join(map(str, args))}")
    if origin in (typing.Union, types.UnionType):
        for option in args:
            try:
                return convert(option, text, whole)
            except ValueError:
                continue
        raise ValueError(f"{text!r} is none of {inner}")
    if origin is tuple:
        items = [t.strip() for t in text.split(",") if t.strip()]
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(convert(args[0], t, whole) for t in items)
        if len(items) != len(args):
            raise ValueError(f"{text!r}: {len(args)} comma-separated values expected")
        return tuple(convert(a, t, whole) for a, t in zip(args, items, strict=True))
    if inner is bool:
        if text.lower() in _TRUE + _FALSE:
            return text.lower() in _TRUE
        raise ValueError(f"{text!r} is not true or false")
    if inner is int:
        return int(text)
    if inner is float:
        return float(text)
    if inner in (str, Path):
        return inner(text)
    raise ValueError(f"a {getattr(inner, '__name__', inner)} is not set from the command line")


def parse_override(cls: type, item: str, whole: Whole | None = None) -> tuple[str, Any]:
    """``"a.b=VALUE"`` -> ``("a.b", VALUE as the field's type)``.

    Raises:
        ValueError: one line naming the override and what is wrong.
    """
    path, eq, text = item.partition("=")
    path = path.strip().replace("-", "_")
    try:
        if not eq or not path:
            raise ValueError("expected FIELD=VALUE")
        return path, convert(resolve(cls, path), text.strip(), whole)
    except ValueError as e:
        raise ValueError(f"--set {item}: {e}") from None


def apply_overrides(config: Any, overrides: Sequence[tuple[str, Any]]) -> Any:
    """``config`` with each ``(dotted path, value)`` replaced, in order; a nested config that
    is ``None`` is built from its defaults first. The configs' ``__post_init__`` checks run
    (their ``ValueError`` is raised as is)."""
    for path, value in overrides:
        config = _replace(config, path.split("."), value)
    return config


def _replace(config: Any, names: list[str], value: Any) -> Any:
    head, *rest = names
    if not rest:
        return dataclasses.replace(config, **{head: value})
    inner = getattr(config, head)
    if inner is None:
        inner = _config_type(_hints(type(config))[head])()
    return dataclasses.replace(config, **{head: _replace(inner, rest, value)})
