"""One writer per output: an advisory lock held for the whole command that writes an output.

A dataset folder (``collect``), a checkpoint folder (``train``), an improvement run
(``improve``) and a study's results and local storage (``tune``) are each written by one
process at a time. The lock is ``fcntl.flock`` on a small file *beside* the output,
``PARENT/.NAME.lock`` (beside rather than inside, so that a checkpoint folder can be swapped
as a whole, :func:`safe_bc.data.atomic.replace_dir`): the kernel releases it when its holder
exits, however it exits (a crash or ``kill -9`` included), so a stale lock never blocks
anyone. The holder writes its pid and command line into the file and removes the file when
it is done; a second process does not wait: it gets :class:`OutputLockedError` naming the
holder, before it has written anything.

The lock is advisory and local: it protects outputs on one machine's file systems. On a
cluster it is held on whatever node runs the command; ``flock`` on NFS is emulated with
byte-range locks (NFSv4, Linux >= 2.6.12), and an object store (``s3://``) has no lock at
all (see the README, *Running on a Ray cluster*).
"""

from __future__ import annotations

import errno
import fcntl
import os
import shutil
import sys
from collections.abc import Iterable, Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path


class OutputLockedError(RuntimeError):
    """Another process holds the output's lock. The message is one line naming it."""


def lock_path(output: str | Path) -> Path:
    """The lock file of ``output``: ``PARENT/.NAME.lock`` of the output's resolved path (every
    symlink followed, the output itself included), so that two names of one folder (a link and
    its target) share one lock."""
    real = Path(os.path.abspath(output)).resolve()
    return real.parent / f".{real.name}.lock"


def _holder(path: Path) -> str:
    try:
        text = path.read_text(errors="replace").strip()
    except OSError:
        return "pid unknown"
    if not text:
        return "pid unknown"
    pid, _, command = text.partition(" ")
    command = " ".join(command.split())
    if len(command) > 120:
        command = command[:117] + "..."
    return f"pid {pid}" + (f", `{command}`" if command else "")


MIN_FREE_BYTES = 1 << 20
"""Free space below which an output is refused before any work (what a run will write is not
known in advance; this catches a full disk)."""


def check_output_folder(output: str | Path, flag: str = "--out") -> None:
    """Before any work: ``output`` is (or can be made) a folder this process can write, on a
    file system that is not full.

    Raises:
        ValueError: one line naming ``output`` and what is wrong.
    """
    path = Path(output)
    if path.exists() and not path.is_dir():
        raise ValueError(f"{flag} {output}: exists and is not a folder; name a folder")
    existing = path
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise ValueError(f"{flag} {output}: {existing} is a file, not a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise ValueError(
            f"{flag} {output}: {existing} is not writable (read-only file system or no "
            "permission); choose another place"
        )
    free = shutil.disk_usage(existing).free
    if free < MIN_FREE_BYTES:
        raise ValueError(
            f"{flag} {output}: the file system of {existing} is full ({free} bytes free)"
        )


@contextmanager
def output_lock(output: str | Path, flag: str = "--out") -> Iterator[Path]:
    """Hold ``output``'s lock for the ``with`` block (creating its parent if needed), after
    :func:`check_output_folder`.

    Args:
        output: the folder a command writes.
        flag: how the user named it, for the message (``--out``, ``--results``, ...).

    Raises:
        OutputLockedError: another process (or another ``with`` in this one) holds it.
        ValueError: ``output`` is a file, not writable, or on a full file system.
    """
    check_output_folder(output, flag)
    path = lock_path(output)
    created = [d for d in (path.parent, *path.parent.parents) if not d.exists()]
    while True:
        path.parent.mkdir(parents=True, exist_ok=True)
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except FileNotFoundError:  # a parent removed meanwhile (see below): make it again
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            os.close(fd)
            if e.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise
            _remove_empty(created)
            raise OutputLockedError(
                f"{output} is being written by another safe-bc process ({_holder(path)}); "
                f"wait for it to finish or choose another {flag} (lock: {path})"
            ) from None
        try:  # the holder before us may have removed the file after we opened it
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    try:
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()} {' '.join(sys.argv)}\n".encode(errors="replace"))
        yield path
    finally:
        try:
            path.unlink(missing_ok=True)  # still held: nobody else can be using this file
        finally:
            os.close(fd)
        _remove_empty(created)  # folders made only for the lock (a command that wrote keeps them)


def _remove_empty(folders: list[Path]) -> None:
    for folder in folders:  # deepest first
        try:
            folder.rmdir()
        except OSError:
            return


@contextmanager
def output_locks(outputs: Iterable[tuple[str | Path, str]]) -> Iterator[None]:
    """Hold the locks of several ``(output, flag)`` pairs, in the order given (all or none)."""
    with ExitStack() as stack:
        seen: set[Path] = set()
        for output, flag in outputs:
            if lock_path(output) not in seen:
                seen.add(lock_path(output))
                stack.enter_context(output_lock(output, flag))
        yield


__all__ = [
    "OutputLockedError",
    "check_output_folder",
    "lock_path",
    "output_lock",
    "output_locks",
]
