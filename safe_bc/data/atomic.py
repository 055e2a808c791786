"""Atomic file writes: a reader sees the old file or the whole new one, never a partial one.

Every file safe_bc writes for keeps (datasets, tables, checkpoints, reports, figures) goes
through :func:`atomic_write`: the data goes to a temporary file in the target's directory,
is flushed and fsynced, then renamed over the target (``os.replace``, atomic on POSIX); on
any error the temporary file is removed and the old target is left as it was.

A folder of files that belong together (a checkpoint: weights, config, selection) goes
through :func:`atomic_dir`: its files are written into a temporary sibling folder, which
then replaces the folder as a whole (one ``renameat2(RENAME_EXCHANGE)`` on Linux), so a
reader sees the old unit or the new one, never a mix.
"""

from __future__ import annotations

import ctypes
import errno
import json
import os
import shutil
import tempfile
from collections.abc import Callable, Collection, Iterator
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


DIR_MODE = 0o755
"""Permissions of a folder written by :func:`atomic_dir` (``mkdtemp`` would leave ``0o700``)."""
_AT_FDCWD = -100
_RENAME_EXCHANGE = 2


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths in one step (Linux ``renameat2(RENAME_EXCHANGE)``); ``False`` where the
    system or the file system cannot."""
    try:
        renameat2 = ctypes.CDLL(None, use_errno=True).renameat2
    except (AttributeError, OSError):
        return False
    rc = renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE)
    if rc == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP, errno.ENOTSUP):
        return False
    raise OSError(err, os.strerror(err), str(b))


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


Keep = Callable[[Path, Path, Path], bool]
"""``keep(entry, old, new)``: whether ``entry``, an entry of the replaced folder ``old`` that is
not part of the unit, moves into the new folder ``new``; one it refuses is removed with
``old``."""


def _carry(old: Path, new: Path, unit: Collection[str], keep: Keep | None = None) -> None:
    """Move the entries of ``old`` that are not part of the unit, that ``new`` lacks and that
    ``keep`` (when given) accepts (e.g. an evaluation folder kept inside a checkpoint folder)
    into ``new``."""
    for entry in sorted(old.iterdir()):
        if entry.name in unit or os.path.lexists(new / entry.name):
            continue
        if keep is None or keep(entry, old, new):
            os.rename(entry, new / entry.name)


def _leftovers(path: Path) -> list[Path]:
    return sorted(
        p
        for kind in ("new", "old")
        for p in path.parent.glob(f".{path.name}.{kind}-*")
        if p.is_dir() and not p.is_symlink()
    )


def recover_dir(path: str | Path, unit: Collection[str] = (), keep: Keep | None = None) -> None:
    """Finish what an interrupted :func:`atomic_dir` of ``path`` left: a folder moved aside
    and not replaced is moved back, entries that were being carried over are carried (those
    ``keep`` accepts), and the temporary folders are removed. Call it holding ``path``'s lock
    (:mod:`safe_bc.data.locks`)."""
    path = Path(path)
    for stale in _leftovers(path):
        if stale.name.startswith(f".{path.name}.old-") and not os.path.lexists(path):
            os.rename(stale, path)  # the old unit, moved aside before a crash
            continue
        if os.path.isdir(path):
            _carry(stale, path, unit, keep)
        shutil.rmtree(stale)


@contextmanager
def atomic_dir(
    path: str | Path, unit: Collection[str] = (), keep: Keep | None = None
) -> Iterator[Path]:
    """Yield an empty temporary folder beside ``path``; on a clean exit it replaces ``path``.

    Readers see the old folder or the new one whole: the swap is one
    ``renameat2(RENAME_EXCHANGE)`` where Linux and the file system support it, else two
    renames (a crash between them leaves ``path`` missing until the next write to it, which
    moves the old folder back: :func:`recover_dir`). Entries of the old folder whose names
    are not in ``unit`` and that the new one lacks (an ``eval/`` folder inside a checkpoint
    folder) are moved into the new one, unless ``keep`` (``keep(entry, old, new)``) refuses
    them: those go with the old folder. On any error the temporary folder is removed and
    ``path`` is left as it was. Meant for a writer that holds ``path``'s lock.

    >>> import tempfile
    >>> target = Path(tempfile.mkdtemp()) / "unit"
    >>> with atomic_dir(target) as tmp:
    ...     _ = (tmp / "a.txt").write_text("one")
    >>> (target / "keep.txt").write_text("not part of the unit")
    20
    >>> with atomic_dir(target, unit={"a.txt", "b.txt"}) as tmp:
    ...     _ = (tmp / "b.txt").write_text("two")
    >>> sorted(p.name for p in target.iterdir()), sorted(p.name for p in target.parent.iterdir())
    (['b.txt', 'keep.txt'], ['unit'])
    """
    path = Path(path)
    if path.is_symlink():  # replace the folder it points to, not the link
        path = path.resolve()
    if path.exists() and not path.is_dir():
        raise FileExistsError(errno.EEXIST, "exists and is not a folder", str(path))
    if path.resolve() in (Path.cwd(), *Path.cwd().parents):
        raise ValueError(f"{path} is the working folder or one above it; name an output folder")
    path.parent.mkdir(parents=True, exist_ok=True)
    recover_dir(path, unit, keep)
    staging = Path(tempfile.mkdtemp(prefix=f".{path.name}.new-", dir=path.parent))
    try:
        yield staging
        os.chmod(staging, DIR_MODE)
        _fsync_dir(staging)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    if not os.path.lexists(path):
        os.rename(staging, path)
        _fsync_dir(path.parent)
        return
    if _exchange(staging, path):
        old = staging  # now holds the old folder
    else:
        old = Path(tempfile.mkdtemp(prefix=f".{path.name}.old-", dir=path.parent))
        try:
            os.rename(path, old)  # replaces the empty folder mkdtemp made
        except BaseException:
            shutil.rmtree(staging, ignore_errors=True)
            old.rmdir()
            raise
        os.rename(staging, path)
    _fsync_dir(path.parent)
    # from here an error leaves the old folder beside ``path`` for recover_dir to finish
    _carry(old, path, unit, keep)
    shutil.rmtree(old)
