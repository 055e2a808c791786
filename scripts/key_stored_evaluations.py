"""Move the committed stored evaluations of comparison cells from their run folders
(``OUT/<runs>_runs/<row>/seed<k>/episodes.parquet``, ``steps.parquet``) to the files named by
what made them (``OUT/stored_evaluations/<key>.parquet``, :mod:`safe_bc.eval_store`), with
``git mv`` and the contents unchanged: the key is that of the stamp each file records, so the runner
finds every one again where it now looks.

Run from the repository root: ``python -m scripts.key_stored_evaluations`` (``--dry-run``
prints the moves only). Two files of one stamp that are byte for byte the same become one;
two of one stamp that differ stop the script before anything moves.
"""

from __future__ import annotations

import argparse
import subprocess
from pathlib import Path

from safe_bc.data.store import read_table_metadata
from safe_bc.eval_store import episodes_path, steps_path

ROOT = Path(__file__).resolve().parents[1]
NAMES = {"episodes.parquet": episodes_path, "steps.parquet": steps_path}
"""A run folder's evaluation files and where each goes, given its output folder and stamp."""


def tracked_evaluations(root: Path = ROOT) -> list[Path]:
    """The committed evaluation files still under a ``*_runs`` folder, relative to ``root``."""
    listed = subprocess.run(
        ["git", "ls-files", "-z", "--", *(f"*_runs/*{name}" for name in NAMES)],
        cwd=root, capture_output=True, check=True, text=True,
    ).stdout  # fmt: skip
    return [Path(p) for p in sorted(listed.split("\0")) if p]


def output_folder(path: Path) -> Path:
    """The comparison output folder above ``path``'s ``<runs>_runs`` folder."""
    runs = [i for i, part in enumerate(path.parts) if part.endswith("_runs")]
    if not runs:
        raise ValueError(f"{path} is under no <runs>_runs folder")
    return Path(*path.parts[: runs[-1]])


def plan_moves(paths: list[Path], root: Path = ROOT) -> list[tuple[Path, Path]]:
    """``(from, to)`` per file (``to`` relative to ``root``); raises when two files of one
    stamp differ."""
    moves: list[tuple[Path, Path]] = []
    first: dict[Path, Path] = {}
    for path in paths:
        stamp = read_table_metadata(root / path).get("stamp")
        if stamp is None:
            raise ValueError(f"{path} records no stamp")
        target = NAMES[path.name](output_folder(path), stamp)
        other = root / first[target] if target in first else root / target
        if other.is_file() and other.read_bytes() != (root / path).read_bytes():
            raise ValueError(f"{other} and {path} have one stamp but differ")
        first.setdefault(target, path)
        moves.append((path, target))
    return moves


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dry-run", action="store_true", help="print the moves only")
    args = parser.parse_args(argv)
    moves = plan_moves(tracked_evaluations())
    done: set[Path] = set()
    for source, target in moves:
        print(f"{source} -> {target}")
        if args.dry_run:
            continue
        if target in done or (ROOT / target).exists():  # the same evaluation, stored twice
            subprocess.run(["git", "rm", "-q", "--", str(source)], cwd=ROOT, check=True)
        else:
            (ROOT / target).parent.mkdir(parents=True, exist_ok=True)
            subprocess.run(["git", "mv", "--", str(source), str(target)], cwd=ROOT, check=True)
        done.add(target)
    print(f"{len(moves)} files, {len({t for _, t in moves})} stored evaluations")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
