"""``make tune`` at two commits on one machine, side by side: wall-clock and the study's verdict.

Each run is the default study (``safe-bc tune tune_jobs/default.py``) from a clean checkout of
its commit, one after the other on the same machine with nothing else running; this module
only reads what the two runs wrote (``timing.parquet``, ``final.parquet``,
``final_paired.parquet``, ``best.json``), copies those tables under ``OUT/<label>/`` and writes
``OUT/side_by_side.parquet`` and ``.md``: per run its revision, wall-clock (the study's
``timing`` rows: total, tuning loop, final phase), the winner, its re-evaluated reward, its
paired difference to the expert (95% CI) and its final-phase episodes beyond d_s; then the new
run's wall-clock as a share of the old one's.

    python -m scripts.tune_side_by_side --run old=DIR --run new=DIR --out OUT [--demos old=DEMOS]
    python -m scripts.tune_side_by_side --out OUT   # again, from the copies in OUT
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path
from typing import Any

import pandas as pd

from safe_bc.data.atomic import write_text_atomic
from safe_bc.data.store import dataset_record, read_table, write_table_atomic

TABLES = (
    "timing.parquet", "timing.md", "trials.parquet", "final.parquet", "final_paired.parquet",
    "best.json",
)  # fmt: skip
"""What is copied from each run's study folder (and read back from the copies)."""
FINAL_PHASES = ("final_train", "final_stages", "final_evaluation", "final_summary", "final_tables")


def run_row(label: str, folder: Path) -> dict[str, Any]:
    """One run's row from its study folder (or its copy)."""
    timing, meta = read_table(folder / "timing.parquet")
    study = timing[timing["part_of"] == "study"].set_index("phase")["seconds"]
    slots = timing[timing["part_of"] == "tuning slots"].set_index("phase")["seconds"]
    final, _ = read_table(folder / "final.parquet")
    paired, _ = read_table(folder / "final_paired.parquet")
    best = json.loads((folder / "best.json").read_text())
    winner = best["trial_id"]
    row = final.set_index("method").loc[winner]
    vs = paired[(paired["method"] == winner) & (paired["vs"] == "expert")].iloc[0]
    prov = meta.get("provenance", meta)
    return {
        "run": label,
        "revision": str(prov.get("git_revision", meta.get("git_revision", "")))[:12],
        "cpu_model": str(prov.get("cpu_model", "")),
        "wall_s": float(study.sum()),
        "tuning_s": float(study.get("tuning", 0.0)),
        "final_s": float(sum(study.get(p, 0.0) for p in FINAL_PHASES)),
        "final_train_s": float(study.get("final_train", 0.0)),
        "final_evaluation_s": float(study.get("final_evaluation", 0.0)),
        "certification_s": float(study.get("certification", 0.0)),
        "trials_train_s": float(slots.get("trial_train", 0.0)),
        "trials_evaluation_s": float(slots.get("trial_evaluation", 0.0)),
        "winner": winner,
        "winner_reward": float(row["reward"]),
        "d_reward_vs_expert": float(vs["d_reward"]),
        "d_reward_lo": float(vs["d_reward_lo"]),
        "d_reward_hi": float(vs["d_reward_hi"]),
        "episodes_beyond_d_s": int(row["episodes_with_violation"]),
        "episodes": int(row["n_episodes"]),
        "feasible": bool(row["feasible"]),
    }


def record_inputs(folder: Path, demos: Path) -> None:
    """Add the demonstrations a run read (:func:`safe_bc.data.store.dataset_record` of
    ``demos``) to the metadata of each copied table of ``folder`` that records none (a run
    made before tables recorded them); the rows are left as they are."""
    record = {"demos": dataset_record(demos), "recorded_by": "scripts.tune_side_by_side"}
    for path in sorted(folder.glob("*.parquet")):
        table, meta = read_table(path)
        if "inputs" not in meta:
            write_table_atomic(path, table, {**meta, "inputs": record})


def inputs_of(folder: Path) -> str:
    """The digest of the demonstrations a run's trial table records (``""``: none)."""
    meta = read_table(folder / "trials.parquet")[1]
    return str(meta.get("inputs", {}).get("demos", {}).get("digest", ""))


def side_by_side(rows: list[dict[str, Any]]) -> pd.DataFrame:
    """The rows, each run's wall-clock as a share of the first run's."""
    table = pd.DataFrame(rows)
    base = table.iloc[0]
    for col in ("wall_s", "tuning_s", "final_s", "trials_train_s", "trials_evaluation_s",
                "final_train_s", "final_evaluation_s"):  # fmt: skip
        table[f"{col}_vs_{base['run']}"] = table[col] / base[col]
    return table


def markdown(table: pd.DataFrame, meta: dict[str, Any]) -> str:
    """The table as Markdown with what it supports."""
    base, last = table.iloc[0], table.iloc[-1]
    b = base["run"]
    ratio = {c[: -len(f"_vs_{b}")]: last[c] for c in table.columns if c.endswith(f"_vs_{b}")}
    verdict = []
    for _, r in table.iterrows():
        lo, hi = r["d_reward_lo"], r["d_reward_hi"]
        where = "above" if lo > 0 else "below" if hi < 0 else "no reliable difference from"
        verdict.append(
            f"{r['run']}: winner {r['winner']} {r['d_reward_vs_expert']:+.1f} "
            f"[{lo:.1f}, {hi:.1f}] against the expert ({where} it), "
            f"{r['episodes_beyond_d_s']} of {r['episodes']} final episodes beyond d_s"
        )
    shown = table[[c for c in table.columns if not c.endswith(f"_vs_{b}")]].copy()
    for col in [c for c in shown.columns if c.endswith("_s") and c != "episodes_beyond_d_s"]:
        shown[col] = shown[col].map(lambda s: f"{s:.0f} s")
    return (
        "# `make tune` side by side\n\n"
        + (
            meta.get("setting")
            or f"The default study run at each commit, one after the other on one machine "
            f"({base['cpu_model']}), nothing else running"
        )
        + "; made by "
        "`python -m scripts.tune_side_by_side` from the runs' own tables (copied beside "
        "this file).\n\n"
        + shown.to_markdown(index=False, floatfmt=".3g")
        + f"\n\n**Wall-clock:** {last['run']} took {ratio['wall_s']:.2f}x {b}'s "
        f"({last['wall_s'] / 60:.1f} against {base['wall_s'] / 60:.1f} min; tuning loop "
        f"{ratio['tuning_s']:.2f}x, final phase {ratio['final_s']:.2f}x). The trials' own "
        f"seconds: training {ratio['trials_train_s']:.2f}x, evaluation "
        f"{ratio['trials_evaluation_s']:.2f}x; the final phase's training "
        f"{ratio['final_train_s']:.2f}x, evaluation {ratio['final_evaluation_s']:.2f}x. "
        "Training seconds follow the settings the searcher picked (batch size, width), which "
        "differ between the runs: `trials.parquet` in each folder has them.\n\n"
        "**The study's own measure** (final phase: each winner retrained with 3 seeds on 51 "
        "fresh tracks, paired with the expert on the same tracks; one draw per commit, and the "
        "two runs' experts drive different frames when the renderer differs, so the runs are "
        "compared through their differences to their own expert, not paired with each other):"
        "\n\n" + "\n".join(f"- {v}" for v in verdict) + "\n\n"
        f"Commands: {meta.get('commands', '')}\n"
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--run", action="append", default=[], help="LABEL=STUDY_DIR, oldest first")
    p.add_argument("--out", type=Path, required=True, help="where the copies and tables go")
    p.add_argument("--commands", default="", help="how the runs were made (recorded)")
    p.add_argument("--setting", default="", help="how the runs relate, when not one after the "
                   "other on one machine with nothing else running (recorded)")  # fmt: skip
    p.add_argument(
        "--demos",
        action="append",
        default=[],
        help="LABEL=DIR: the demonstrations of a run whose tables name none",
    )
    args = p.parse_args(argv)
    demos = dict(tuple(d.split("=", 1)) for d in args.demos)
    runs = [tuple(r.split("=", 1)) for r in args.run]
    if any(len(r) != 2 for r in runs):
        p.error("--run takes LABEL=STUDY_DIR")
    if runs:
        for label, folder in runs:
            dest = args.out / label
            dest.mkdir(parents=True, exist_ok=True)
            for name in TABLES:
                shutil.copy2(Path(folder) / name, dest / name)
            if label in demos:
                record_inputs(dest, Path(demos[label]))
        labels = [label for label, _ in runs]
    else:
        old, _ = read_table(args.out / "side_by_side.parquet")
        labels = list(old["run"])
    rows = [run_row(label, args.out / label) for label in labels]
    table = side_by_side(rows)
    meta = {"runs": labels, "commands": args.commands, "setting": args.setting,
            "inputs": {label: inputs_of(args.out / label) for label in labels}}  # fmt: skip
    if not runs:
        before = read_table(args.out / "side_by_side.parquet")[1]
        meta["commands"], meta["setting"] = before.get("commands", ""), before.get("setting", "")
    write_table_atomic(args.out / "side_by_side.parquet", table, meta)
    write_text_atomic(args.out / "side_by_side.md", markdown(table, meta))
    print(markdown(table, meta))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
