"""Draw a study folder's ``pareto.png`` again from its tables, as the study draws it at the end
of its final phase: the trials (``trials.parquet``, with the threshold and objective its
metadata records), the final phase's candidates (``final.parquet``, role ``candidate``) and
its winner (``best.json``, ringed only where the final phase found it feasible), the safety
axis in the task's words. No table is written. ``python -m scripts.pareto_figure
results/default``."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from safe_bc.data.store import read_table
from safe_bc.plots import plot_pareto
from safe_bc.study.plan import safety_axis_label

FINISHED = ("done", "stopped", "invalid", "error")
"""Trial states the study counts as finished in the figure's title."""


def draw(out: Path) -> Path:
    """``out / "pareto.png"`` from the study tables in ``out``."""
    trials, meta = read_table(out / "trials.parquet")
    study = meta.get("study", {})
    final, _ = read_table(out / "final.parquet")
    best = json.loads((out / "best.json").read_text())
    feasible = bool(best.get("feasible"))
    finished = int(trials["status"].isin(FINISHED).sum())
    verdict = f"winner {best['trial_id']}" if feasible else "no candidate feasible"
    return plot_pareto(
        trials,
        float(meta["threshold"]),
        out / "pareto.png",
        winner=best["trial_id"] if feasible else None,
        candidates=list(final.loc[final["role"] == "candidate", "method"]),
        title=f"{study.get('name', out.name)}: {finished}/{study.get('trials', len(trials))} "
        f"trials; final phase: {verdict}",
        objective=meta.get("objective", "reward_mean"),
        safety_label=safety_axis_label(study["env"]["env_id"]),
    )


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print("usage: python -m scripts.pareto_figure STUDY_DIR", file=sys.stderr)
        return 2
    print(f"wrote {draw(Path(args[0]))}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
