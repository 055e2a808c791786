"""Write a study folder's ``timing.parquet`` and ``timing.md`` again from its ``timing.jsonl`` and
``trials.parquet`` (the command, provenance and inputs the trial table records), as the study
itself writes them at its end: ``python -m scripts.timing_table results/default``."""

from __future__ import annotations

import sys
from pathlib import Path

from safe_bc.data.store import read_table
from safe_bc.study.run import write_timing


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print("usage: python -m scripts.timing_table STUDY_DIR", file=sys.stderr)
        return 2
    out = Path(args[0])
    trials, meta = read_table(out / "trials.parquet")
    write_timing(out, trials, meta)
    print(f"wrote {out / 'timing.parquet'} and timing.md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
