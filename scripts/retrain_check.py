"""Behaviour check: retrain rows of the committed Table 1 with the current code and compare.

Usage::

    python -m scripts.retrain_check      # 3 rows: plain BC, alpha 0.5, BC-Safe

Each (method, training seed) row is retrained with ``safe_bc.cli.api.train`` (``safe-bc train``)
with the settings the Table 1 comparison (``tune_jobs/compare/table1.py``) gives that row and
seed (:func:`safe_bc.compare.run.run_config`) on its demonstrations, into a scratch
folder; its final training loss is compared with the committed one of
``results/table1_training.parquet`` to the last digit: refactors that must not change results
are checked on real training, not only on unit tests. Writes
``results/checks/table1_retrain.parquet`` (committed loss and its revision, retrained loss,
whether they are identical, the retrained weights' SHA-256) and prints a Markdown table; exit
status 1 when a loss differs.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import pandas as pd

from safe_bc.compare.families import load_comparison
from safe_bc.compare.spec import Comparison
from safe_bc.data.provenance import run_metadata
from safe_bc.data.store import read_table, write_table_atomic

ROWS = (("alpha=0 (rest=all)", 0), ("alpha=0.5 (rest=all)", 1), ("BC-Safe (K=20)", 2))
"""(method, training seed) rows checked by default: the mix at two alphas and a peer rule."""
TABLE1 = Path("tune_jobs/compare/table1.py")


def retrain(
    comparison: Comparison, rows: tuple[tuple[str, int], ...], training: pd.DataFrame, revision: str
) -> pd.DataFrame:
    """Retrain ``rows`` of ``comparison``; one row each against the committed ``training``."""
    from safe_bc.cli.api import train
    from safe_bc.cli.jobs import TrainJob
    from safe_bc.compare.run import run_config

    out = []
    for method, seed in rows:
        committed = training[(training["method"] == method) & (training["train_seed"] == seed)]
        run = run_config(comparison, comparison.method(method), seed)
        with tempfile.TemporaryDirectory() as d:
            train(TrainJob(Path(d) / "agent", comparison.demos, run, quiet=True))
            stored = json.loads((Path(d) / "agent/config.json").read_text())
        loss = float(stored["extra"]["train"]["final_loss"])
        before = float(committed["final_loss"].iloc[0])
        out.append({"method": method, "train_seed": seed, "committed_final_loss": before,
                    "committed_revision": revision, "retrained_final_loss": loss,
                    "identical": loss == before,
                    "weights_sha256": stored["weights_sha256"]})  # fmt: skip
    return pd.DataFrame(out)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--comparison", type=Path, default=TABLE1)
    p.add_argument("--out", type=Path, default=Path("results/checks/table1_retrain.parquet"))
    args = p.parse_args(argv)
    comparison = load_comparison(args.comparison)
    source = comparison.out / f"{comparison.name}_training.parquet"
    training, meta = read_table(source)
    table = retrain(comparison, ROWS, training, meta["git_revision"])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_table_atomic(args.out, table, run_metadata(source=str(source), rows=list(ROWS)))
    print(table.drop(columns="weights_sha256").to_markdown(index=False, floatfmt=".17g"))
    return 0 if table["identical"].all() else 1


if __name__ == "__main__":
    sys.exit(main())
