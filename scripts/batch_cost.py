"""What a study's deterministic batches cost in wall-clock, replayed from its trial durations.

Usage::

    .venv/bin/python -m scripts.batch_cost results/default --slots 2

Reads ``trials.parquet`` (``duration_s`` in suggestion order, ``trial_number``, and the study
spec it records: ``max_concurrent``, ``batch_size``; ``--slots`` for a study that ran as many
trials at once as the CPUs allowed, ``max_concurrent=None``) and prints the trial phase's wall-clock
replayed on that many slots in batches (:func:`safe_bc.study.spec.schedule_seconds`) against the
same trials started as slots free up (no batches). Nothing is written: the inputs are
committed tables.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from safe_bc.data.store import read_table
from safe_bc.study.spec import schedule_seconds


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("study", type=Path, help="a study's result folder")
    p.add_argument("--slots", type=int, help="trials at once (default: the study's max_concurrent)")
    args = p.parse_args(argv)
    trials, meta = read_table(args.study / "trials.parquet")
    spec = meta["study"]
    if (args.slots or spec.get("max_concurrent")) is None:
        print(f"{args.study}: the study ran as many trials at once as the CPUs allowed "
              "(max_concurrent=None): give --slots N", file=sys.stderr)  # fmt: skip
        return 2
    slots = int(args.slots or spec["max_concurrent"])
    batch = spec.get("batch_size", slots)
    if batch is None:
        print(f"{args.study}: the study ran without batches (batch_size=None)")
        return 0
    durations = trials.sort_values("trial_number")["duration_s"].astype(float).tolist()
    batched = schedule_seconds(durations, slots, batch)
    free = schedule_seconds(durations, slots, None)
    print(f"{args.study}: {len(durations)} trials ({min(durations):.0f}-{max(durations):.0f} s "
          f"each) on {slots} slots: {batched:.0f} s in batches of {batch}, {free:.0f} s "
          f"unbatched ({batched / free - 1:+.0%})")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
