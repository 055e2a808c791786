"""Two designs of a study, replicate against replicate, on the study's own final-phase measure.

Usage::

    .venv/bin/python -m scripts.design_replicates \\
        --design two_seeds=results/default_two_seeds \\
        --design half=results/default \\
        --out results/checks/make_tune/half/replicates

Each ``--design LABEL=FOLDER`` is a study folder whose ``replicates/r<k>/`` hold finished
replicate studies (``safe-bc tune STUDY --replicates N``). For every replicate the winner
(``best.json``) and the expert are paired on the same final-phase tracks
(``final_episodes.parquet``: the winner's training seed ``s`` and the expert's block of that
seed share their tracks); a design's episodes are pooled over its replicates. Per design: the
winner's reward minus the expert's (mean, 95% two-level bootstrap: the (replicate, training
seed) cells, then the tracks within a cell), its episodes beyond d_s with the one-sided 95%
Clopper-Pearson bound on their share, and the replicates whose own interval
(``replicates.parquet``) lies above zero, below it or spans it. Then the second design minus
the first on both (independent bootstraps; the share of episodes beyond d_s by a bootstrap of
the same cells), and the replicates whose winners share a configuration in both designs
(the same final phase). Writes ``OUT.parquet`` and ``OUT.md``; nothing is evaluated again.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from safe_bc.data.atomic import write_text_atomic
from safe_bc.data.provenance import run_metadata
from safe_bc.data.store import read_table, write_table_atomic
from safe_bc.metrics import bootstrap_means, clopper_pearson_upper
from safe_bc.study.replicates import direction

BOOT = 4000
"""Bootstrap resamples."""
SEED = 0
"""Bootstrap seed."""


def paired_episodes(folder: Path) -> pd.DataFrame:
    """One row per winner episode of every replicate under ``folder/replicates``: ``replicate``,
    ``train_seed``, ``env_seed``, ``d_reward`` (winner minus expert, same track),
    ``any_violation`` (the winner's)."""
    rows = []
    for rdir in sorted((folder / "replicates").glob("r*"), key=lambda p: int(p.name[1:])):
        winner = json.loads((rdir / "best.json").read_text())["trial_id"]
        ep, _ = read_table(rdir / "final_episodes.parquet")
        mine = ep[ep["method"] == winner].set_index(["train_seed", "env_seed"])
        expert = ep[ep["method"] == "expert"].set_index(["train_seed", "env_seed"])
        if mine.empty or set(mine.index) - set(expert.index):
            raise ValueError(f"{rdir}: no winner episodes, or some without the expert's track")
        part = pd.DataFrame({
            "d_reward": mine["reward"] - expert.loc[mine.index, "reward"],
            "any_violation": mine["any_violation"].astype(float),
        }).reset_index()  # fmt: skip
        part.insert(0, "replicate", int(rdir.name[1:]))
        rows.append(part)
    if not rows:
        raise ValueError(f"{folder}: no replicates/r<k>/ folders")
    return pd.concat(rows, ignore_index=True)


def cell_draws(frame: pd.DataFrame, column: str, rng: np.random.Generator) -> np.ndarray:
    """``BOOT`` two-level bootstrap means of ``column``: (replicate, seed) cells, then rows."""
    cells = frame.groupby(["replicate", "train_seed"]).ngroup().to_numpy()
    return bootstrap_means(frame[column].to_numpy(float), cells, n_boot=BOOT, rng=rng)


def same_winner(a: pd.DataFrame, b: pd.DataFrame) -> list[int]:
    """Replicates (by index) whose winners have the same searched configuration in both
    replicate tables: the same final phase, so the same episodes on one machine type."""
    keys = [c for c in a.columns if c.startswith(("selection.", "bc.", "improve.", "queries."))]
    if not keys or set(keys) - set(b.columns):
        return []
    left, right = a.set_index("replicate")[keys], b.set_index("replicate")[keys]
    both = left.index.intersection(right.index)
    return [int(k) for k in both if left.loc[k].astype(str).equals(right.loc[k].astype(str))]


def verdict(lo: float, hi: float) -> str:
    """What an interval supports."""
    return {"above": "reliably above", "below": "reliably below"}.get(
        direction(lo, hi), "no reliable difference"
    )


def compare(designs: dict[str, pd.DataFrame], tables: dict[str, pd.DataFrame]) -> pd.DataFrame:
    """One row per design, then one row of the last design minus the first."""
    rng = np.random.default_rng(SEED)
    rows, draws = [], {}
    for label, ep in designs.items():
        d, v = cell_draws(ep, "d_reward", rng), cell_draws(ep, "any_violation", rng)
        draws[label] = (d, v)
        k, n = int(ep["any_violation"].sum()), len(ep)
        t = tables[label]
        rows.append({
            "design": label, "replicates": int(ep["replicate"].nunique()),
            "cells": int(ep.groupby(["replicate", "train_seed"]).ngroups), "episodes": n,
            "distinct_winners": int(t["winner"].nunique()),
            "winners_feasible": int(t["winner_feasible"].sum()),
            "d_reward": float(ep["d_reward"].mean()),
            "d_reward_lo": float(np.quantile(d, 0.025)),
            "d_reward_hi": float(np.quantile(d, 0.975)), "beyond_d_s": k,
            "beyond_share_ucb": clopper_pearson_upper(k, n, 0.95),
            "share": k / n, "share_lo": float(np.quantile(v, 0.025)),
            "share_hi": float(np.quantile(v, 0.975)),
            "replicates_above": int((t["vs_expert"] == "above").sum()),
            "replicates_below": int((t["vs_expert"] == "below").sum()),
            "replicates_spanning": int((t["vs_expert"] == "spans zero").sum()),
        })  # fmt: skip
    first, last = next(iter(designs)), list(designs)[-1]
    dd = draws[last][0] - draws[first][0]
    dv = draws[last][1] - draws[first][1]
    a, b = rows[0], rows[-1]
    rows.append({
        "design": f"{last} - {first}", "d_reward": b["d_reward"] - a["d_reward"],
        "same_winner": ",".join(f"r{k}" for k in same_winner(tables[first], tables[last])),
        "d_reward_lo": float(np.quantile(dd, 0.025)), "d_reward_hi": float(np.quantile(dd, 0.975)),
        "share": b["share"] - a["share"], "share_lo": float(np.quantile(dv, 0.025)),
        "share_hi": float(np.quantile(dv, 0.975)),
    })  # fmt: skip
    return pd.DataFrame(rows)


def design_inputs(folder: Path) -> dict[str, dict[str, Any]]:
    """Per replicate of the design at ``folder``, the demonstrations its final phase read: the
    digest its tables record, else (made before digests were recorded) the described set its
    ``d_s`` match (:func:`scripts.input_sets.described_set`)."""
    from safe_bc.data.store import read_table_metadata
    from scripts.input_sets import described_set

    out = {}
    for rdir in sorted((folder / "replicates").glob("r*"), key=lambda p: int(p.name[1:])):
        final = rdir / "final.parquet"
        meta = read_table_metadata(final) if final.is_file() else {}
        demos = (meta.get("inputs") or {}).get("demos") or {}
        if demos.get("digest"):
            out[rdir.name] = {"digest": demos["digest"], "identified_by": "its tables"}
        else:
            out[rdir.name] = described_set(meta.get("cost_limits")) or {"digest": None}
    return out


def markdown(table: pd.DataFrame, meta: dict) -> str:
    """The table in words and numbers."""
    shown = []
    for _, r in table.iterrows():
        if pd.isna(r.get("episodes")):
            continue
        shown.append({
            "design": r["design"], "replicates x seeds x tracks":
                f"{int(r['replicates'])} x {int(r['cells']) // int(r['replicates'])} x "
                f"{int(r['episodes']) // int(r['cells'])}",
            "winner - expert (95% CI)": f"{r['d_reward']:+.1f} [{r['d_reward_lo']:+.1f}, "
                                        f"{r['d_reward_hi']:+.1f}]",
            "replicates above / below / spanning": f"{int(r['replicates_above'])} / "
                f"{int(r['replicates_below'])} / {int(r['replicates_spanning'])}",
            "beyond d_s": f"{int(r['beyond_d_s'])}/{int(r['episodes'])}",
            "share bound (CP 95%)": f"{r['beyond_share_ucb']:.3f}",
            "distinct winners": int(r["distinct_winners"]),
            "winners feasible": f"{int(r['winners_feasible'])}/{int(r['replicates'])}",
        })  # fmt: skip
    diff = table.iloc[-1]
    first, last = table.iloc[0]["design"], table.iloc[-2]["design"]
    words = (
        f"**{last} minus {first}:** winner minus expert {diff['d_reward']:+.1f} "
        f"[{diff['d_reward_lo']:+.1f}, {diff['d_reward_hi']:+.1f}] "
        f"({verdict(diff['d_reward_lo'], diff['d_reward_hi'])}); share of final episodes beyond "
        f"d_s {diff['share']:+.3f} [{diff['share_lo']:+.3f}, {diff['share_hi']:+.3f}] "
        f"({verdict(diff['share_lo'], diff['share_hi'])})."
    )
    same = diff.get("same_winner") or ""
    if same:
        words += (
            f" Replicates {same.replace(',', ', ')} chose the same winning configuration in "
            "both designs, so their final episodes are the same ones: the difference rests "
            "on the other replicates, and the bootstrap, which treats the designs as "
            "independent, is wider than a paired one would be."
        )
    return "\n".join([
        "# The study's designs, replicate against replicate", "",
        "Each design's replicate studies (the same study, seeds shifted); every replicate's "
        "winner paired with the expert on its final phase's fresh tracks, pooled over the "
        "replicates (95% two-level bootstrap: (replicate, training seed) cells, then tracks; "
        f"{BOOT} resamples, seed {SEED}). Made by `{meta['command']}`; nothing evaluated again.",
        "", pd.DataFrame(shown).to_markdown(index=False), "", words, "",
        "Sources: " + ", ".join(f"`{k}`: `{v}`" for k, v in meta["designs"]) + ".", "",
    ])  # fmt: skip


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--design", action="append", required=True, metavar="LABEL=FOLDER",
                   help="a study folder with replicates/ (give two)")  # fmt: skip
    p.add_argument("--out", type=Path, required=True, help="OUT.parquet and OUT.md")
    args = p.parse_args(argv)
    pairs = [d.split("=", 1) for d in args.design]
    if len(pairs) != 2 or any(len(x) != 2 for x in pairs):
        print("error: give exactly two --design LABEL=FOLDER", file=sys.stderr)
        return 2
    designs, tables = {}, {}
    for label, folder in pairs:
        try:
            designs[label] = paired_episodes(Path(folder))
            tables[label] = read_table(Path(folder) / "replicates.parquet")[0]
        except (OSError, ValueError) as e:
            print(f"error: {folder}: {str(e).splitlines()[0]}", file=sys.stderr)
            return 2
    table = compare(designs, tables)
    meta = run_metadata(
        command="python -m scripts.design_replicates " + " ".join(
            f"--design {a}={b}" for a, b in pairs) + f" --out {args.out}",
        designs=[list(x) for x in pairs], bootstrap_seed=SEED, resamples=BOOT,  # in order
        inputs={label: design_inputs(Path(folder)) for label, folder in pairs},
    )  # fmt: skip
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_table_atomic(args.out.with_suffix(".parquet"), table, meta)
    md = markdown(table, meta)
    write_text_atomic(args.out.with_suffix(".md"), md)
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
