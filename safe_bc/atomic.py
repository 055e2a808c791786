"""Atomic file writes: a reader sees the old file or the whole new one, never a partial one.

Every file safe_bc writes for keeps (datasets, tables, checkpoints, reports, figures) goes
through :func:`atomic_write`: the data goes to a temporary file in the target's directory,
is flushed and fsynced, then renamed over the target (``os.replace``, atomic on POSIX); on
any error the temporary file is removed and the old target is left as it was.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

FILE_MODE = 0o644
"""Permissions of a written file (``mkstemp`` would leave it ``0o600``)."""


@contextmanager
def atomic_write(
    path: str | Path, mode: str = "wb", *, encoding: str | None = None
) -> Iterator[IO[Any]]:
    """Open a temporary file next to ``path``; on a clean exit it replaces ``path``.

    Args:
        path: the target; its directory is created if needed.
        mode: ``"wb"`` (binary) or ``"w"`` (text).
        encoding: for text mode (default: the locale's, as ``open``).

    >>> import tempfile
    >>> target = Path(tempfile.mkdtemp()) / "note.txt"
    >>> with atomic_write(target, "w") as f:
    ...     _ = f.write("hello")
    >>> target.read_text()
    'hello'
    >>> with atomic_write(target, "w") as f:
    ...     _ = f.write("half a")
    ...     raise RuntimeError("interrupted")
    Traceback (most recent call last):
    RuntimeError: interrupted
    >>> target.read_text(), [p.name for p in target.parent.iterdir()]
    ('hello', ['note.txt'])
    """
    if mode not in ("wb", "w"):
        raise ValueError(f"mode must be 'wb' or 'w', not {mode!r}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, mode, encoding=encoding) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, FILE_MODE)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_bytes_atomic(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_write(path, "wb") as f:
        f.write(data)


def write_text_atomic(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (locale encoding, as ``Path.write_text``)."""
    with atomic_write(path, "w") as f:
        f.write(text)


def write_json_atomic(path: str | Path, obj: Any, *, indent: int | None = 2, **dumps: Any) -> None:
    """Write ``json.dumps(obj, indent=indent, **dumps)`` and a newline to ``path`` atomically.

    >>> import tempfile
    >>> target = Path(tempfile.mkdtemp()) / "a.json"
    >>> write_json_atomic(target, {"x": [1, 2]}, indent=None)
    >>> target.read_text()
    '{"x": [1, 2]}\\n'
    """
    write_text_atomic(path, json.dumps(obj, indent=indent, **dumps) + "\n")
