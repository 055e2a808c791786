"""Collect the drift's release-distance sweep again: ``python -m scripts.release_sweep [FILE]``
(``FILE`` defines ``SWEEP = ReleaseSweep(...)``; default ``tune_jobs/sweeps/drift_release.py``).
Writes ``OUT/release_sweep.parquet`` and ``release_sweep.md``
(:mod:`safe_bc.rollout.release_sweep`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from safe_bc.rollout.release_sweep import DEFAULT_FILE, load_sweep, run_sweep


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("file", nargs="?", type=Path, default=DEFAULT_FILE)
    args = parser.parse_args(argv)
    run_sweep(load_sweep(args.file))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
