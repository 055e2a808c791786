"""Progress of the long commands: a tqdm bar on a terminal; off one (stderr a file or a pipe:
a log), a plain line every :data:`PLAIN_EVERY` seconds and one at the end of work that took
that long, with no carriage returns; nothing when the command's ``--quiet`` asks for it."""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable, Iterator
from typing import Any

from tqdm.auto import tqdm

PLAIN_EVERY = 30.0
"""Seconds between two plain progress lines in a log (a study's phases last minutes)."""


class PlainProgress:
    """The part of tqdm's interface the commands use, written as plain lines to ``file``: one
    every ``every`` seconds while work goes on and one when it ends, if it lasted that long
    (short work prints nothing)."""

    def __init__(
        self,
        iterable: Iterable[Any] | None = None,
        *,
        total: float | None = None,
        desc: str = "",
        unit: str = "it",
        file: Any = None,
        every: float = PLAIN_EVERY,
        initial: float = 0,
        **_: Any,
    ) -> None:
        self.iterable, self.desc, self.unit, self.every = iterable, desc, unit, every
        if total is None and iterable is not None and hasattr(iterable, "__len__"):
            total = len(iterable)  # type: ignore[arg-type]
        self.total, self.file, self.n = total, file, initial
        self.postfix = ""
        self.start = self.last = time.monotonic()
        self.printed = False

    def _stream(self) -> Any:
        return self.file if self.file is not None else sys.stderr

    def _line(self, now: float) -> None:
        of = f"/{self.total:g}" if self.total is not None else ""
        share = f" ({100 * self.n / self.total:.0f}%)" if self.total else ""
        tail = f", {self.postfix}" if self.postfix else ""
        text = f"{self.desc}: {self.n:g}{of} {self.unit}{share}, {now - self.start:.0f} s{tail}"
        print(text, file=self._stream(), flush=True)
        self.last, self.printed = now, True

    def update(self, n: float = 1) -> None:
        self.n += n
        now = time.monotonic()
        if now - self.last >= self.every:
            self._line(now)

    def set_postfix(self, ordered_dict: Any = None, refresh: bool = True, **kwargs: Any) -> None:
        items = {**(ordered_dict or {}), **kwargs}
        self.postfix = ", ".join(f"{k}={v}" for k, v in items.items())

    def refresh(self) -> None:
        """Nothing to redraw: lines are written as time passes."""

    def write(self, s: str) -> None:
        print(s, file=self._stream(), flush=True)

    def close(self) -> None:
        now = time.monotonic()
        if now - self.start >= self.every:
            self._line(now)
        self.every = float("inf")  # closed: no further lines

    def __iter__(self) -> Iterator[Any]:
        assert self.iterable is not None, "iterate a progress made with an iterable"
        for item in self.iterable:
            yield item
            self.update()
        self.close()

    def __enter__(self) -> PlainProgress:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def progress_bar(*, show: bool = True, **kwargs: Any) -> Any:
    """Progress of long work (``kwargs`` as tqdm's): a tqdm bar when its stream (``file``,
    default stderr) is a terminal, a :class:`PlainProgress` off one, disabled with
    ``show=False``."""
    if not show:
        return tqdm(disable=True, **kwargs)
    stream = kwargs.get("file") or sys.stderr
    if getattr(stream, "isatty", lambda: False)():
        return tqdm(**kwargs)
    return PlainProgress(**kwargs)
