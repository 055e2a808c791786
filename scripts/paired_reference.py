"""Every policy of an improvement table against the expert on the same tracks (or patients).

Usage::

    .venv/bin/python -m scripts.paired_reference results/improve/carracing
    .venv/bin/python -m scripts.paired_reference results/table1_episodes.parquet

Reads ``episodes.parquet`` of each folder (written by the earlier improvement scripts; the
comparison runner writes ``<name>_episodes.parquet``: name it), or the episode table named
(Table 1's): the expert evaluated once,
every other policy per training seed, all on the same tracks. Writes ``paired_expert.parquet``
beside it (for a named table ``<stem>_paired_expert.parquet``):
:func:`safe_bc.metrics.paired_to_reference` (crossed bootstrap over training seeds and tracks,
bootstrap seed 0) of reward, violation steps and the share of episodes beyond ``d_s``; its
metadata's ``inputs`` are the episode table's (its demonstrations) and that table's sha256. Prints
a Markdown table per folder. Nothing is rerun.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

from safe_bc.data.provenance import file_digest, run_metadata
from safe_bc.data.store import read_table, write_table_atomic
from safe_bc.metrics import paired_to_reference
from safe_bc.report import fmt_ci

METRICS = ("reward", "violation_steps", "any_violation", "violating_sessions")
"""Compared where the episodes hold them (``violating_sessions``: the rehab replay's)."""


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folders", type=Path, nargs="+",
                   help="improvement result folders, or episode tables (.parquet)")  # fmt: skip
    p.add_argument("--reference", default="expert", help="the policy evaluated once")
    args = p.parse_args(argv)
    for folder in args.folders:
        source = folder if folder.suffix == ".parquet" else folder / "episodes.parquet"
        target = (folder.with_name(f"{folder.stem}_paired_{args.reference}.parquet")
                  if folder.suffix == ".parquet"
                  else folder / f"paired_{args.reference}.parquet")  # fmt: skip
        episodes, meta = read_table(source)
        metrics = [m for m in METRICS if m in episodes and episodes[m].notna().any()]
        paired = paired_to_reference(episodes, args.reference, metrics, seed=0)
        out_meta = run_metadata(
            reference=args.reference,
            bootstrap_seed=0,
            source={"table": str(source), "command": meta.get("command"),
                    "git_revision": meta.get("git_revision")},
        )  # fmt: skip
        out_meta["inputs"] = {
            **meta.get("inputs", {}),
            "episodes": {str(source): file_digest(source)},
        }
        write_table_atomic(target, paired, out_meta)
        view = pd.DataFrame({"method": paired["method"], "pairs": paired["n_pairs"]})
        for m in metrics:
            digits = 3 if "any" in m else 1
            view[f"{m} - {args.reference}"] = [
                fmt_ci(r, f"d_{m}", digits, signed=True) for _, r in paired.iterrows()
            ]
        view["seeds better (reward)"] = (
            paired["seeds_better"].astype(str) + " / " + paired["n_seeds_paired"].astype(str)
        )
        print(f"## {folder}\n\n{view.to_markdown(index=False)}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
