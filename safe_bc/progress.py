"""Progress bars of the long commands: tqdm, shown on a terminal only (quiet when stderr, where
the bar is drawn, is a file or a pipe, and when the command's ``--quiet`` asks for it)."""

from __future__ import annotations

from typing import Any

from tqdm.auto import tqdm


def progress_bar(*, show: bool = True, **kwargs: Any) -> tqdm:
    """A tqdm bar (``kwargs`` as tqdm's); ``show=False`` disables it, and tqdm itself disables
    it off a terminal (``disable=None``)."""
    return tqdm(disable=None if show else True, **kwargs)
