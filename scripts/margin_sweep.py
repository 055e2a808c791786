"""The margin sweep's table from its episode tables (an analysis of committed tables).

Usage::

    .venv/bin/python -m scripts.margin_sweep          # after the three comparisons
    cd results/improve/rehab/sweep && python -m scripts.margin_sweep \\
        --selection selection.parquet --test test.parquet --out /tmp/sweep  # the committed run

The episodes come from ``safe-bc compare tune_jobs/compare/margin_sweep.py --name
sweep_selection`` (selection patients) and ``--name sweep_test`` (test patients); the candidates,
the rule and the
tested list live in ``tune_jobs/compare/margin_sweep.py``. Per candidate: the paired gain over
the guideline clinician on the same patients (the guideline, trained once, stands in for
every training seed; crossed bootstrap over seeds and patients, bootstrap seed 0) and the
programmes with a session beyond d_s (the last session included: ``violating_sessions`` of
the evaluation path). Tables of the run before the comparison runner hold the reward as
``replay_reward`` (the same value, from a replay); their gain keeps that name, which seeds its
bootstrap, so they re-derive exactly.

Writes ``OUT/<tag>sweep.parquet`` (one row per candidate) and ``OUT/<tag>margin_sweep.md``.
"""

from __future__ import annotations

import argparse
import importlib.util
import shlex
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from safe_bc.report import fmt_ci

SWEEP_FILE = Path(__file__).resolve().parents[1] / "tune_jobs/compare/margin_sweep.py"


def sweep_spec() -> Any:
    """The module ``tune_jobs/compare/margin_sweep.py`` (candidates, base, tested, offset)."""
    spec = importlib.util.spec_from_file_location("margin_sweep", SWEEP_FILE)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def reward_column(df: pd.DataFrame) -> str:
    """``replay_reward`` in tables of the run before the comparison runner, else ``reward``."""
    return "replay_reward" if "replay_reward" in df else "reward"


def gains(df: pd.DataFrame, names: list[str], seeds: list[int], prefix: str) -> pd.DataFrame:
    """Per candidate: paired gain over the guideline (crossed bootstrap CI: every seed on the
    same patients) and crossings."""
    from safe_bc.metrics import paired_crossed

    if df.empty or not names:
        return pd.DataFrame({"method": []})
    reward = reward_column(df)
    expert = df[df["method"] == "expert"]
    pairs = [expert.assign(train_seed=k) for k in seeds]
    pairs.append(df[df["method"].isin(names)])
    paired = paired_crossed(pd.concat(pairs), "expert", [reward], by="method", better=None, seed=0)
    crossed = df.assign(any=df["violating_sessions"] > 0).groupby("method")
    rows = []
    for _, r in paired.iterrows():
        m = r["method"]
        rows.append({
            "method": m,
            f"{prefix}_gain": r[f"d_{reward}"],
            f"{prefix}_gain_lo": r[f"d_{reward}_lo"],
            f"{prefix}_gain_hi": r[f"d_{reward}_hi"],
            f"{prefix}_patients_beyond": int(crossed["any"].sum()[m]),
            f"{prefix}_sessions_beyond": int(crossed["violating_sessions"].sum()[m]),
            f"{prefix}_n": int(crossed.size()[m]),
        })  # fmt: skip
    return pd.DataFrame(rows)


def sweep_table(selection: pd.DataFrame, test: pd.DataFrame, tested: list[str]) -> pd.DataFrame:
    """One row per candidate (the start first): selection and test gains and crossings."""
    methods = [m for m in dict.fromkeys(selection["method"]) if m != "expert"]
    names = ["imitation", *[m for m in methods if m != "imitation"]]
    seeds = train_seeds(selection)
    table = gains(selection, names, seeds, "select")
    tested = [t for t in tested if t in set(test["method"])]
    table = table.merge(gains(test, tested, seeds, "test"), on="method", how="left")
    table["seeds"] = len(seeds)
    order = {m: i for i, m in enumerate(names)}
    return table.sort_values("method", key=lambda s: s.map(order)).reset_index(drop=True)


def expert_beyond(df: pd.DataFrame) -> int:
    """The guideline clinician's programmes with a session beyond d_s."""
    return int((df.loc[df["method"] == "expert", "violating_sessions"] > 0).sum())


def markdown(sweep: pd.DataFrame, meta: dict[str, Any], spec: Any) -> str:
    """The sweep's table, its rule and the provenance."""

    def ci(r: pd.Series, p: str) -> str:
        return fmt_ci(r, f"{p}_gain", 2, signed=True, blank_missing=True)

    def count(r: pd.Series, p: str) -> str:
        if not np.isfinite(r.get(f"{p}_n", np.nan)):
            return "not tested" if p == "test" else ""
        return f"{int(r[f'{p}_patients_beyond'])} / {int(r[f'{p}_n'])}"

    rows = []
    for _, r in sweep.iterrows():
        tested = np.isfinite(r.get("test_n", np.nan))
        rows.append({
            "candidate": r["method"],
            "overrides": ", ".join(f"{k}={v}" for k, v in spec.CANDIDATES.get(r["method"], {})
                                   .items()),
            "seeds": int(r["seeds"]),
            "selection gain": ci(r, "select"),
            "selection beyond d_s": count(r, "select"),
            "test gain": ci(r, "test"),
            "test beyond d_s": count(r, "test"),
            "test sessions beyond d_s": int(r["test_sessions_beyond"]) if tested else "",
        })  # fmt: skip
    offset = spec.SELECT_OFFSET
    lines = [
        "# Safety-margin sweep: constrained improvement on the rehabilitation pathway",
        "",
        f"Training seeds {meta['seeds']}. Gain: capacity gain minus the guideline clinician's "
        "on the same patients (paired; mean [95% crossed bootstrap CI over training seeds and "
        "patients, bootstrap seed 0]). *beyond d_s*: programmes with at least one session "
        "(the last included) beyond the worst the guideline reached on its demonstrations.",
        "",
        f"Selection patients ({meta['select_n']} per seed, validation indices {offset}.."
        f"{offset + meta['select_n'] - 1}, disjoint from training, keep and test patients) "
        f"choose; the test patients ({meta['test_n']} held-out) were used once per candidate "
        f"in this order: {', '.join(meta['tested']) or 'none'}. Every tested candidate is "
        "listed; nothing was tuned on them. Rule: screen every candidate on training seed 0, "
        "run the promising ones on all 3 seeds, and choose the highest 3-seed selection gain "
        "among the candidates with no selection programme beyond d_s.",
        "",
        pd.DataFrame(rows).to_markdown(index=False),
        "",
        f"Guideline clinician on the same patients: {meta['expert_select_beyond']} / "
        f"{meta['select_n']} selection and {meta['expert_test_beyond']} / {meta['test_n']} "
        "test programmes beyond d_s.",
        "",
        "Provenance:",
        "",
        f"* command: `{meta['command']}`",
        f"* episodes: {meta['sources']}",
        f"* git revision: `{meta['git_revision']}`, created {meta['created_utc']}",
        f"* base config: `{spec.BASE.to_dict()}`",
        "",
    ]
    return "\n".join(lines)


def train_seeds(episodes: pd.DataFrame) -> list[int]:
    """The training seeds of the trained rows."""
    trained = episodes.loc[episodes["method"] != "expert", "train_seed"]
    return sorted(int(s) for s in trained.unique())


def main(argv: list[str] | None = None) -> int:
    from safe_bc.data.provenance import run_metadata
    from safe_bc.data.store import read_table, write_table_atomic, write_text_atomic

    sweep_dir = Path("results/improve/rehab/sweep")
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--selection", type=Path, default=sweep_dir / "sweep_selection_episodes.parquet")
    p.add_argument("--test", type=Path, default=sweep_dir / "sweep_test_episodes.parquet")
    p.add_argument("--out", type=Path, default=sweep_dir)
    p.add_argument("--tag", default="", help="prefix of the output files")
    args = p.parse_args(argv)
    command = shlex.join(["python", "-m", "scripts.margin_sweep",
                          *(sys.argv[1:] if argv is None else argv)])  # fmt: skip
    spec = sweep_spec()
    selection, _ = read_table(args.selection)
    test, _ = read_table(args.test) if args.test.exists() else (selection.iloc[:0], {})
    sweep = sweep_table(selection, test, spec.TESTED)
    n_select = int(selection.loc[selection["method"] == "expert", "env_seed"].nunique())
    n_test = int(test.loc[test["method"] == "expert", "env_seed"].nunique()) if len(test) else 0
    meta = run_metadata(
        seeds=train_seeds(selection),
        select_n=n_select,
        test_n=n_test,
        tested=[t for t in spec.TESTED if len(test) and t in set(test["method"])],
        expert_select_beyond=expert_beyond(selection),
        expert_test_beyond=expert_beyond(test),
        sources=f"`{args.selection}`, `{args.test}`",
    )
    meta["command"] = command
    args.out.mkdir(parents=True, exist_ok=True)
    write_table_atomic(args.out / f"{args.tag}sweep.parquet", sweep, meta)
    text = markdown(sweep, meta, spec)
    write_text_atomic(args.out / f"{args.tag}margin_sweep.md", text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
