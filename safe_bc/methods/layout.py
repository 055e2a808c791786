"""The run folder every round-based method shares (pure: names only): its identity record, its
done mark, its policy folder and one folder per round (:mod:`safe_bc.methods.rounds` reads and
writes them; each method's config module hands these names on)."""

from __future__ import annotations

IDENTITY = "identity.json"
"""The run's identity record."""
DONE = "done.json"
"""The mark of a finished run."""
POLICY = "policy"
"""The folder of the run's final policy."""


def round_dir(r: int) -> str:
    """Folder name of round ``r`` (``round_000``).

    >>> round_dir(7)
    'round_007'
    """
    return f"round_{r:03d}"
