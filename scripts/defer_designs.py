"""Every deferral design of the car's self-imitation agent on its fresh tracks, in one
table and one figure (an analysis of committed comparison tables).

Usage::

    python -m scripts.defer_designs

Reads each fresh-track table of :data:`TABLES` (``safe-bc compare
tune_jobs/compare/handover.py --name NAME``; a table not committed yet is skipped) and
writes ``results/selfimprove/carracing/defer_designs.md`` and ``defer_designs.png``: per
deferral row of the self-imitation agent (and the agent alone on the same tracks), episodes
beyond d_s of seeds x tracks with the one-sided 95% Clopper-Pearson upper bound, the reward
against the expert (paired, crossed 95% interval) and the mean share of deferred steps. The
figure puts the burden (deferred steps) against the bound, with the goal (bound <= 2%,
i.e. 0 of 150, and under 5% of steps) shaded. Each design was chosen on selection tracks
before its fresh block was run; the blocks differ, so rows of different tables are not paired
with each other.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import pandas as pd

from safe_bc.metrics import clopper_pearson_upper

ROOT = Path(__file__).resolve().parents[1]
FOLDER = ROOT / "results/selfimprove/carracing"
TABLES = (
    "defer", "defer_wide", "defer_lookahead", "defer_trend", "defer_corner",
    "defer_corner_replication",
)  # fmt: skip
"""The fresh-track tables, in the order they were run."""
AGENT = "selfimitation"
GOAL_BOUND, GOAL_BURDEN = 0.02, 0.05
"""The deferral goal: the crossing share's 95% bound at most 2% (0 of 150), deferred steps < 5%."""


def rows(table: pd.DataFrame, meta: dict[str, Any], name: str) -> list[dict[str, Any]]:
    """The agent's and its deferral rows of one fresh-track table."""
    labels = {m["name"]: m.get("label") or m["name"] for m in meta["config"]["methods"]}
    out = []
    for _, r in table.iterrows():
        method = r["method"]
        if method != AGENT and not method.startswith(f"{AGENT}+defer"):
            continue
        k, n = int(r["episodes_with_violation"]), int(r["n_episodes"])
        share = r.get("deferred_share")
        out.append(
            {
                "table": name,
                "block": int(meta["config"]["eval_seed"]),
                "code": meta["git_revision"][:7],
                "design": "agent alone" if method == AGENT else _design(labels[method]),
                "beyond d_s": f"{k}/{n}",
                "95% bound": clopper_pearson_upper(k, n),
                "reward vs expert": f"{r['d_reward']:+.1f} [{r['d_reward_lo']:.1f}, "
                f"{r['d_reward_hi']:.1f}]",
                "steps deferred": float(share) if pd.notna(share) else float("nan"),
                "seeds x tracks": f"{int(r['n_train_seeds'])}x{int(r['n_tracks'])}",
            }
        )
    return out


def _design(label: str) -> str:
    """The deferral part of a row label (``..., expert within 2 px ...`` -> ``expert within
    2 px ...``)."""
    return label.split("), ", 1)[-1] if "), " in label else label


def summary(folder: Path = FOLDER) -> pd.DataFrame:
    """Every committed fresh-track table's rows (:func:`rows`), in :data:`TABLES` order."""
    from safe_bc.data.store import read_table

    out: list[dict[str, Any]] = []
    for name in TABLES:
        path = folder / f"{name}.parquet"
        if path.exists():
            out += rows(*read_table(path), name)
    return pd.DataFrame(out)


def meets_goal(table: pd.DataFrame) -> pd.Series:
    """Rows whose crossing bound is at most 2% with under 5% of steps deferred (the reward
    condition is read from the table's interval beside it)."""
    return (table["95% bound"] <= GOAL_BOUND) & (table["steps deferred"] < GOAL_BURDEN)


def markdown(table: pd.DataFrame, command: str) -> str:
    """The summary as Markdown, with which rows meet the goal."""
    shown = table.assign(
        **{
            "95% bound": table["95% bound"].map(lambda x: f"{x:.1%}"),
            "steps deferred": table["steps deferred"].map(
                lambda x: "" if pd.isna(x) else f"{x:.1%}"
            ),
            "bound and burden met": meets_goal(table).map({True: "yes", False: ""}),
        }
    )
    return "\n".join(
        [
            "# Deferral designs of the car's self-imitation agent on fresh tracks (issue 35)",
            "",
            "Each deferral design was chosen on selection tracks (block 18) by a rule fixed "
            "before its fresh block was run; each block was new to it. Goal: 0 of 150 beyond d_s "
            "(95% bound <= 2%), reward not reliably below the expert's, under 5% of steps "
            "deferred. Rows of different blocks are not paired with each other.",
            "",
            shown.to_markdown(index=False),
            "",
            f"Command: `{command}`.",
            "",
        ]
    )


def figure(table: pd.DataFrame, path: Path) -> None:
    """Burden (deferred steps) against the 95% bound on the crossing share, one point per
    deferral row, the goal's corner shaded."""
    import matplotlib.pyplot as plt

    from safe_bc.plots import save_figure

    d = table.dropna(subset=["steps deferred"])
    fig, ax = plt.subplots(figsize=(7.5, 4.5))
    ax.fill_between([0, GOAL_BURDEN * 100], 0, GOAL_BOUND * 100, color="tab:green", alpha=0.2)
    ax.axhline(GOAL_BOUND * 100, color="tab:green", lw=0.8, ls="--")
    ax.axvline(GOAL_BURDEN * 100, color="tab:green", lw=0.8, ls="--")
    for i, (_, r) in enumerate(d.iterrows()):
        x, y = 100 * r["steps deferred"], 100 * r["95% bound"]
        label = f"{r['design']}: {r['beyond d_s']} (block {r['block']})"
        ax.plot(x, y, "os^Dv<>P"[i % 8], ms=7, label=label)
    ax.legend(fontsize=7, loc="upper right")
    ax.set_xlim(0, max(20.0, 100 * d["steps deferred"].max() + 6))
    ax.set_xlabel("steps deferred to the expert (%, mean per episode)")
    ax.set_ylabel("95% upper bound on episodes beyond d_s (%)")
    ax.set_title("Deferral designs on fresh tracks: burden against crossings (goal: green)")
    ax.set_ylim(0, max(6.0, 100 * d["95% bound"].max() + 1))
    save_figure(fig, path)


def main(argv: list[str] | None = None) -> int:
    from safe_bc.data.atomic import write_text_atomic

    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.parse_args(argv)
    table = summary()
    if table.empty:
        print("no fresh-track deferral table committed", file=sys.stderr)
        return 2
    command = "python -m scripts.defer_designs"
    text = markdown(table, command)
    write_text_atomic(FOLDER / "defer_designs.md", text)
    figure(table, FOLDER / "defer_designs.png")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
