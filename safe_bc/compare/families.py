"""Loading a family file (``tune_jobs/compare/<family>.py``): its comparisons by address,
fresh ones resolved.

A family declares ``COMPARISONS``: :class:`~safe_bc.compare.spec.Comparison` specs and
:class:`~safe_bc.compare.protocol.Fresh` ones. Loading a fresh comparison is the one place a spec
depends on a file beyond its own: its rows are chosen (:func:`safe_bc.compare.protocol.resolve`) on
its selection's committed table, read then.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from safe_bc.compare.protocol import Fresh, resolve
from safe_bc.compare.spec import Comparison
from safe_bc.config_file import run_config_file

FAMILY = "COMPARISONS"
"""The name a family file gives its comparisons: a tuple of :class:`Comparison` and
:class:`~safe_bc.compare.protocol.Fresh` (each addressed by its name), or a dict from address to one
(where two comparisons of the family share a name, writing to different folders)."""

Entry = Comparison | Fresh
"""A family's entry: a comparison, or a fresh comparison resolved when it runs."""


def family(path: str | Path) -> dict[str, Entry]:
    """The comparisons a family file (``tune_jobs/compare/<family>.py``) declares, by address,
    as declared (a :class:`~safe_bc.compare.protocol.Fresh` one unresolved: nothing is read).

    Raises:
        FileNotFoundError: no such file.
        ValueError: not a Python file, no ``COMPARISONS``, an entry of another type, an address
            used twice, or an invalid spec (one line naming the file).
    """
    module = run_config_file(path, "comparison file", "tune_jobs/compare/*.py", "safe_bc_compare_")
    declared = getattr(module, FAMILY, None)
    if isinstance(declared, tuple):
        keys = [c.name for c in declared if isinstance(c, Entry)]
        dup = sorted({k for k in keys if keys.count(k) > 1})
        if dup:
            raise ValueError(f"{path}: comparisons share names {dup}: give them addresses (a dict)")
        declared = {getattr(c, "name", repr(c)): c for c in declared}
    if not isinstance(declared, dict) or not declared:
        raise ValueError(f"{path}: defines no {FAMILY} = (Comparison(...), ...)")
    for key, entry in declared.items():
        if not isinstance(entry, Entry):
            raise ValueError(f"{path}: {key!r} is a {type(entry).__name__}, not a Comparison")
    return declared


def _resolved(path: Path, entries: dict[str, Entry], key: str, planned: bool = False) -> Comparison:
    """Entry ``key`` ready to run: a fresh comparison's rows chosen on its selection's
    committed table (``OUT/<selection name>.parquet``, read now). ``planned``: a fresh
    comparison whose selection has not run yet stands as its selection's rows without the
    candidates, on its own tracks (what the track ledger needs)."""
    entry = entries[key]
    if isinstance(entry, Comparison):
        return entry
    if entry.follows not in entries or entry.follows == key:
        raise ValueError(f"{path}: {key!r} follows {entry.follows!r}, no other comparison there")
    from safe_bc.data.store import read_table

    selection = _resolved(path, entries, entry.follows, planned)
    table = selection.out / f"{selection.name}.parquet"
    if not table.is_file() and planned:
        changes: dict[str, Any] = {"name": entry.name, "eval_seed": entry.eval_seed}
        if entry.episodes is not None:
            changes["episodes"] = entry.episodes
        return selection.with_deferral((), shares_tracks_with=entry.shares_tracks_with, **changes)
    if not table.is_file():
        raise FileNotFoundError(
            f"{path}: {key!r} chooses its rows on {table}, which is missing: run "
            f"safe-bc compare {path} --name {entry.follows} first"
        )
    return resolve(entry, selection, read_table(table)[0])


def load_comparisons(path: str | Path, planned: bool = False) -> dict[str, Comparison]:
    """Every comparison of a family file by address, ready to run (fresh comparisons
    resolved: their selections' tables are read now). ``planned``: a fresh comparison whose
    selection has not run yet is included without its chosen rows (on its own tracks) instead
    of refused."""
    entries = family(path)
    return {key: _resolved(Path(path), entries, key, planned) for key in entries}


def load_comparison(path: str | Path, name: str | None = None, planned: bool = False) -> Comparison:
    """The comparison ``name`` of a family file, ready to run (``None``: the file's only one;
    ``planned`` as :func:`load_comparisons`).

    Raises:
        FileNotFoundError: no such file, or a fresh comparison's selection table is missing.
        ValueError: as :func:`family`; or ``name`` is missing or no address of the file (the
            line lists the addresses).
    """
    entries = family(path)
    if name is None and len(entries) == 1:
        name = next(iter(entries))
    if name not in entries:
        what = "name one comparison" if name is None else f"no comparison {name!r}"
        raise ValueError(f"{path}: {what} (--name): {', '.join(entries)}")
    return _resolved(Path(path), entries, name, planned)
