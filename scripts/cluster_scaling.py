"""Trials per minute of a study's tuning loop on a local Ray of N CPUs: one row per run.

Usage::

    python -m scripts.cluster_scaling --cpus 2 --trials 4 --batch-size 16 --out OUT.parquet
    python -m scripts.cluster_scaling --cpus 16 --trials 16 --batch-size 16 --out OUT.parquet
    python -m scripts.cluster_scaling --report OUT.parquet      # OUT.md: the rows + ratios

A run starts a private local Ray with ``num_cpus=N`` (``RAY_ADDRESS`` is ignored), runs the
study (default ``tune_jobs/default.py``; ``--trials``, ``--batch-size`` (default: the trials
that fit N CPUs, ``N // cpus_per_trial``), ``--max-concurrent`` and ``--batches`` override it)
into a temporary folder (``--results`` keeps it) without its final phase, and appends one row
to ``--out`` (a table written with :func:`safe_bc.data.store.write_table_atomic`; a second
run appends to it): CPUs, trials, the tuning loop's wall seconds (``timing.parquet``'s
``tuning`` phase: Tune's ``fit``, every trial, Optuna, the halving), trials per minute, the
concurrency resolved from the CPUs and the most trials seen running at once, the trials' mean
duration, and the machine (:func:`safe_bc.data.provenance.provenance`). ``--report`` writes the
Markdown beside the table, each row's trials per minute against the row with the fewest CPUs.

The demonstrations are ``--demos`` (default ``data/demos``); when absent the study collects the
task's default set there first (outside the timed loop), so a second run reuses them. Nothing
needs the network. The same batch size at every CPU count runs the same study (the same
trials, whatever runs at once); a smaller ``--trials`` runs its first trials.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import pandas as pd

from safe_bc.data.atomic import write_text_atomic
from safe_bc.data.store import read_table, write_table_atomic

DEFAULT_STUDY = Path("tune_jobs/default.py")
COLUMNS = (
    "cpus", "machine_cpus", "study", "trials", "batch_size", "cpus_per_trial", "batches",
    "concurrency", "concurrency_reached", "tuning_seconds", "trials_per_min",
    "trial_seconds_mean", "finished", "cpu_model", "python", "git_revision", "created_utc",
)  # fmt: skip
"""The columns of a row, in order."""


def study_for(args: argparse.Namespace, root: Path) -> Any:
    """The study to measure: the study file with the command line's overrides, writing under
    ``root``."""
    from safe_bc.study.spec import load_study

    spec = load_study(args.study)
    fit = max(1, math.floor(args.cpus / spec.trial_cpus + 1e-9))
    changes: dict[str, Any] = {
        "batch_size": args.batch_size if args.batch_size else fit,
        "max_concurrent": args.max_concurrent,
        "storage": str(root / "ray"),
        "results": root / "results",
        "demos": Path(args.demos) if args.demos else spec.demos,
    }
    if args.trials:
        changes["trials"] = args.trials
    if args.batches:
        changes["batches"] = args.batches
    return replace(spec, **changes)


def measure(args: argparse.Namespace) -> dict[str, Any]:
    """Run the study on a fresh local Ray of ``args.cpus`` CPUs; its row."""
    from safe_bc.data.provenance import provenance
    from safe_bc.distributed.runtime import start_local_ray
    from safe_bc.study.run import run_study

    os.environ.setdefault("RAY_DEDUP_LOGS", "0")
    if os.environ.pop("RAY_ADDRESS", None):
        print("RAY_ADDRESS ignored: this measures a local Ray of --cpus CPUs")
    with tempfile.TemporaryDirectory(prefix="cluster-scaling-") as tmp:
        root = Path(args.results) if args.results else Path(tmp)
        spec = study_for(args, root)
        start_local_ray(num_cpus=args.cpus, log_to_driver=False)
        try:
            t0 = time.perf_counter()
            outcome = run_study(spec, fresh=True, progress=False, final=False,
                                command=" ".join(["python -m scripts.cluster_scaling",
                                                  *sys.argv[1:]]))  # fmt: skip
            print(f"study run: {time.perf_counter() - t0:.0f} s in all")
        finally:
            import ray

            ray.shutdown()
        timing = outcome.timing.set_index("phase")
        tuning_s = float(timing.loc["tuning", "seconds"])
        reached = timing.loc["tuning", "count"]
        trials = outcome.trials
        finished = int(trials["status"].isin(["done", "stopped", "invalid"]).sum())
    prov = provenance()
    return {
        "cpus": int(args.cpus),
        "machine_cpus": int(os.cpu_count() or 0),
        "study": f"{args.study}:{spec.name}",
        "trials": int(spec.trials),
        "batch_size": int(spec.batch_size) if spec.batch_size is not None else None,
        "cpus_per_trial": float(spec.trial_cpus),
        "batches": int(spec.batches),
        "concurrency": int(spec.concurrency(args.cpus)),
        "concurrency_reached": None if pd.isna(reached) else int(reached),
        "tuning_seconds": tuning_s,
        "trials_per_min": 60.0 * finished / tuning_s if tuning_s > 0 else math.nan,
        "trial_seconds_mean": float(pd.to_numeric(trials["duration_s"]).mean()),
        "finished": finished,
        "cpu_model": str(prov.get("cpu_model", "")),
        "python": str(prov.get("python", "")),
        "git_revision": str(prov.get("git_revision", "")),
        "created_utc": str(prov.get("created_utc", "")),
    }


def append_row(path: Path, row: dict[str, Any]) -> pd.DataFrame:
    """Add ``row`` to the table at ``path`` (made if absent); the whole table."""
    from safe_bc.data.provenance import provenance

    rows, meta = read_table(path) if path.exists() else (pd.DataFrame(), {})
    table = pd.concat([rows, pd.DataFrame([row], columns=list(COLUMNS))], ignore_index=True)
    runs = [*meta.get("runs", []), {"command": " ".join(sys.argv), **provenance()}]
    write_table_atomic(path, table, {
        "what": "trials per minute of the study's tuning loop on a local Ray of `cpus` CPUs",
        "made_by": "python -m scripts.cluster_scaling",
        "runs": runs,
        "provenance": runs[-1],
    })  # fmt: skip
    return table


def report(table: pd.DataFrame) -> str:
    """The Markdown view: the rows and each one's trials per minute against the row with the
    fewest CPUs (the first such)."""
    base = table.sort_values("cpus", kind="stable").iloc[0]
    view = table.assign(
        ratio=[f"{r / base['trials_per_min']:.2f}x" for r in table["trials_per_min"]],
        tuning_seconds=[f"{s:.0f}" for s in table["tuning_seconds"]],
        trials_per_min=[f"{r:.2f}" for r in table["trials_per_min"]],
        trial_seconds_mean=[f"{s:.0f}" for s in table["trial_seconds_mean"]],
        git_revision=[str(g)[:10] for g in table["git_revision"]],
    )
    cols = ["cpus", "machine_cpus", "trials", "batch_size", "concurrency", "concurrency_reached",
            "tuning_seconds", "trials_per_min", "ratio", "trial_seconds_mean", "cpu_model",
            "python", "git_revision", "created_utc"]  # fmt: skip
    return "\n".join([
        "# Trials per minute of the study's tuning loop at N CPUs",
        "",
        f"Made by `python -m scripts.cluster_scaling` (see its docstring); `ratio`: trials "
        f"per minute against the {int(base['cpus'])}-CPU row. `concurrency`: trials at once "
        "resolved from the CPUs (at most the batch); `concurrency_reached`: the most seen "
        "running at once. The tuning loop only (Tune's fit), not Ray's start, the "
        "demonstrations or the final phase.",
        "",
        view[cols].to_markdown(index=False, disable_numparse=True),
        "",
    ])  # fmt: skip


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cpus", type=int, help="logical CPUs of the local Ray")
    p.add_argument("--study", type=Path, default=DEFAULT_STUDY, help="a study file")
    p.add_argument("--trials", type=int, help="trials (default: the study's)")
    p.add_argument("--batch-size", type=int, help="the study's batch (default: CPUs // per trial)")
    p.add_argument("--max-concurrent", type=int, help="cap on trials at once (default: none)")
    p.add_argument("--batches", type=int, help="training batches per trial (default: the study's)")
    p.add_argument("--demos", help="demonstrations (default: the study's; collected if absent)")
    p.add_argument("--results", help="keep the study's outputs here (default: a temporary folder)")
    p.add_argument("--out", type=Path, help="the table a row is appended to (.parquet)")
    p.add_argument("--report", type=Path, help="write the Markdown of this table beside it")
    return p


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if args.report:
        table, _ = read_table(args.report)
        text = report(table)
        write_text_atomic(args.report.with_suffix(".md"), text)
        print(text)
        return 0
    if not args.cpus or args.cpus < 1 or args.out is None:
        _parser().error("a run needs --cpus N (>= 1) and --out FILE.parquet")
    row = measure(args)
    table = append_row(args.out, row)
    try:
        print(report(table))
    except ImportError:  # DataFrame.to_markdown needs tabulate, which a bare machine may lack
        print(table.to_string(index=False))
    return 0


if __name__ == "__main__":
    sys.exit(main())
