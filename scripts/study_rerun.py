"""A study rerun from a fresh clone against the committed study: are its tables the same, value
for value? Trial ids (random per Tune run) are set aside, and so are wall-clock seconds; every
other column of the trial table, the final phase's and the certification's tables and episodes
must be equal exactly.

    python -m scripts.study_rerun --rerun DIR --setting "..."   # copies DIR's tables beside
    python -m scripts.study_rerun               # again, from the copies

Writes ``results/checks/make_tune/recommender/rerun/`` (the rerun's tables), ``rerun.parquet``
(one row per table; the setting and both runs' demonstration digests in its metadata) and
``rerun.md``; a test re-derives the report from the committed copies.
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import pandas as pd

from safe_bc.data.store import read_table, write_table_atomic

ROOT = Path(__file__).resolve().parents[1]
STUDY = ROOT / "results" / "default"
OUT = ROOT / "results" / "checks" / "make_tune" / "recommender"
TABLES = (
    "trials.parquet", "final.parquet", "final_episodes.parquet", "final_paired.parquet",
    "certify.parquet", "certify_episodes.parquet",
)  # fmt: skip


def comparable(frame: pd.DataFrame, name: str) -> pd.DataFrame:
    """``frame`` without what differs between identical runs: trial ids, seconds."""
    out = frame.copy()
    if name == "trials.parquet":
        drop = [c for c in out if c in ("trial_id", "resumed") or c.endswith("_seconds")]
        return (
            out.drop(columns=[*drop, "duration_s"])
            .sort_values("trial_number")
            .reset_index(drop=True)
        )
    for col in ("method", "policy"):
        if col in out:  # a candidate is named by its trial id
            out[col] = out[col].astype(str).str.replace(r"^[0-9a-f]{8}", "<trial>", regex=True)
    return out


def difference(a: pd.DataFrame, b: pd.DataFrame) -> str:
    """``""`` when equal exactly, else the first difference in one line."""
    try:
        pd.testing.assert_frame_equal(a, b, check_exact=True)
    except AssertionError as e:
        return " ".join(str(e).split())[:200]
    return ""


def rows(study: Path = STUDY, rerun: Path = OUT / "rerun") -> pd.DataFrame:
    """One row per table: its size and whether the rerun's equals the study's."""
    out = []
    for name in TABLES:
        a = comparable(pd.read_parquet(study / name), name)
        b = comparable(pd.read_parquet(rerun / name), name)
        diff = difference(a, b)
        out.append({"table": name, "rows": len(a), "columns": a.shape[1],
                    "equal": "yes" if not diff else "no", "first difference": diff})  # fmt: skip
    return pd.DataFrame(out)


def report(study: Path = STUDY, rerun: Path = OUT / "rerun") -> str:
    """The Markdown report, with the setting and inputs ``rerun.parquet`` records."""
    _, meta = read_table(OUT / "rerun.parquet")
    digests = ", ".join(f"{k} {v}" for k, v in meta["inputs"].items())
    return (
        "# The default study rerun from a fresh clone\n\n"
        f"{meta['setting']} Trial ids (random per Tune run) and seconds set aside: every value "
        "equal means the rerun gave the same trials, final phase and certificate. "
        f"Demonstrations read: {digests}. Made by `python -m scripts.study_rerun`.\n\n"
        + rows(study, rerun).to_markdown(index=False)
        + "\n"
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rerun", type=Path, help="the rerun's study folder (copied beside)")
    p.add_argument("--setting", default="", help="how the rerun was made (recorded)")
    args = p.parse_args(argv)
    if args.rerun is not None:
        (OUT / "rerun").mkdir(parents=True, exist_ok=True)
        for name in TABLES:
            shutil.copy2(args.rerun / name, OUT / "rerun" / name)
        inputs = {
            label: read_table(folder / "trials.parquet")[1]["inputs"]["demos"]["digest"]
            for label, folder in (("study", STUDY), ("rerun", OUT / "rerun"))
        }
        meta = {"setting": args.setting, "inputs": inputs}
        write_table_atomic(OUT / "rerun.parquet", rows(), meta)
    text = report()
    (OUT / "rerun.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
