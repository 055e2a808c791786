"""Behaviour check: retrain rows of the committed Table 1 with the current code and compare.

Usage::

    .venv/bin/python -m scripts.retrain_check          # 3 rows: plain BC, alpha 0.5, BC-Safe

Each row (method, training seed) of ``results/table1_training.parquet`` is retrained with
``safe_bc.api.train`` (``safe-bc train``: the same demonstrations and selection settings, the
row's training seed)
into a scratch folder, and its final training loss is compared with the committed one to
the last digit: refactors that must not change results (registries, package splits) are
checked on real training, not only on unit tests. Writes
``results/checks/table1_retrain.parquet`` (committed loss and its revision, retrained loss,
whether they are identical, the retrained weights' SHA-256) and prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import pandas as pd

from safe_bc.api import train
from safe_bc.data.store import read_table, write_table_atomic
from safe_bc.jobs import TrainJob
from safe_bc.provenance import run_metadata
from safe_bc.run_config import RunConfig
from safe_bc.selection import RULES, SelectionConfig

ROWS = (("alpha=0 (rest=all)", 0), ("alpha=0.5 (rest=all)", 1), ("BC-Safe (K=20)", 2))
"""(method, training seed) rows checked by default: the mix at two alphas and a peer rule."""


def run_config(method: dict, seed: int) -> RunConfig:
    """The training settings of a Table 1 method (its stored selection settings) and seed."""
    keep = ["mode", "alpha", "rest", "eps", *RULES[method["mode"]].params]
    run = RunConfig(SelectionConfig(**{k: method[k] for k in keep}))
    return replace(run, bc=replace(run.bc, train=replace(run.bc.train, seed=seed)))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--table", type=Path, default=Path("results/table1_training.parquet"))
    p.add_argument("--out", type=Path, default=Path("results/checks/table1_retrain.parquet"))
    args = p.parse_args(argv)
    training, meta = read_table(args.table)
    methods, demos = meta["config"]["methods"], meta["config"]["demos"]
    rows = []
    for method, seed in ROWS:
        committed = training[(training["method"] == method) & (training["train_seed"] == seed)]
        with tempfile.TemporaryDirectory() as d:
            train(TrainJob(Path(f"{d}/agent"), Path(demos), run_config(methods[method], seed),
                           quiet=True))  # fmt: skip
            stored = json.loads(Path(f"{d}/agent/config.json").read_text())
        loss = float(stored["extra"]["train"]["final_loss"])
        before = float(committed["final_loss"].iloc[0])
        rows.append({"method": method, "train_seed": seed, "committed_final_loss": before,
                     "committed_revision": meta["git_revision"], "retrained_final_loss": loss,
                     "identical": loss == before,
                     "weights_sha256": stored["weights_sha256"]})  # fmt: skip
    table = pd.DataFrame(rows)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_table_atomic(args.out, table, run_metadata(source=str(args.table), rows=list(ROWS)))
    print(table.drop(columns="weights_sha256").to_markdown(index=False, floatfmt=".17g"))
    return 0 if table["identical"].all() else 1


if __name__ == "__main__":
    sys.exit(main())
