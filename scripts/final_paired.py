"""Paired differences of a finished study's final phase, from its stored episodes.

Usage::

    .venv/bin/python -m scripts.final_paired results/default results/rehab

For each study folder: reads ``final_episodes.parquet`` (the final phase's episodes) and
writes ``final_paired.parquet`` beside it: every method against the expert and every
candidate against plain BC on the same (training seed, track) pairs, two-level bootstrap
(:func:`safe_bc.study.final.final_summaries`, bootstrap seed = the study's
``final_seed``, the candidates' streams keyed by their stored configurations). Studies run
with the current code write this table themselves; this
command derives it for studies finished before, without rerunning anything. Prints a
Markdown table per study.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

from safe_bc.data.provenance import run_metadata
from safe_bc.data.store import read_table, write_table_atomic
from safe_bc.report import fmt_ci
from safe_bc.study.final import PLAIN_BC, final_summaries


def markdown(paired: pd.DataFrame) -> str:
    """Reward and episodes-beyond-d_s differences, one row per (method, vs)."""
    rows = []
    for _, r in paired.iterrows():
        row = {"method": r["method"], "vs": r["vs"], "pairs": int(r["n_pairs"]),
               "reward, paired": fmt_ci(r, "d_reward", 1, signed=True)}  # fmt: skip
        if "d_any_violation" in r:
            row["share of episodes beyond d_s, paired"] = fmt_ci(
                r, "d_any_violation", 3, signed=True
            )
        rows.append(row)
    return pd.DataFrame(rows).to_markdown(index=False)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("studies", type=Path, nargs="+", help="study result folders")
    args = p.parse_args(argv)
    for folder in args.studies:
        episodes, meta = read_table(folder / "final_episodes.parquet")
        seed = int(meta["final_design"]["final_seed"])
        # the configurations key the candidates' bootstrap streams, as in the study itself
        configs = meta.get("configs") or {}
        candidates = {m: c for m, c in configs.items() if m != PLAIN_BC}
        paired = final_summaries(episodes, candidates, seed)[1]
        source = meta.get("provenance", {})
        out_meta = run_metadata(
            bootstrap_seed=seed,
            source={"table": str(folder / "final_episodes.parquet"),
                    "command": meta.get("command"), "provenance": source},
        )  # fmt: skip
        write_table_atomic(folder / "final_paired.parquet", paired, out_meta)
        print(f"## {folder}\n\n{markdown(paired)}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
