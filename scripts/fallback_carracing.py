"""Diagnostic: would a safe fallback in critical states close CarRacing's violation gap?

Usage::

    .venv/bin/python -m scripts.fallback_carracing          # after scripts.improve_carracing

The shield of ``safe_bc.improve`` hands critical states (measured cost within eps of d_s) to
the frozen imitation start, which itself crosses d_s on most tracks. This script keeps every
trained net and critical zone of ``scripts.improve_carracing``'s runs and swaps only the
fallback for the scripted expert (privileged: it reads the track, so it is *not* a
deployable CarRacing policy; in the clinic it stands for handing a critical decision back to
the clinician). No retraining: the improved agents (``--modes``) and the starts are
evaluated behind an expert fallback on the same held-out tracks, through the one
evaluation path (cached per policy in ``RUNS/evaluations/``, next to the main table's).

Writes ``OUT/episodes.parquet``, ``OUT/summary.parquet``, ``OUT/paired.parquet``
(differences to the same seed's start without a fallback, same tracks) and
``OUT/fallback.md``.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path
from typing import Any

import pandas as pd

from safe_bc.report import fmt_ci, markdown_table
from scripts.eval_cache import evaluate_cached
from scripts.improve_carracing import summary_table
from scripts.improve_rehab import split_policy, write_outputs

LABELS = {
    "expert": "expert (scripted, privileged)",
    "imitation": "safety-imitation start, no fallback",
    "imitation+expert": "start, expert in critical states",
    "both": "shield + Lagrangian (imitation fallback)",
    "both+expert": "shield + Lagrangian agent, expert in critical states",
    "ppo": "PPO, no fallback",
    "ppo+expert": "PPO agent, expert in critical states",
}


def markdown(summary: pd.DataFrame, paired: pd.DataFrame, meta: dict[str, Any]) -> str:
    """The diagnostic table with its provenance."""
    pairs = paired.set_index("method")
    lines = [
        "# Diagnostic: the expert as the shield's fallback (CarRacing)",
        "",
        f"{meta['episodes']} held-out tracks (evaluation seed {meta['eval_seed']}, as in "
        f"`{meta['runs']}/improve.md`), training seeds {meta['train_seeds']}. Same nets and "
        "critical zones as the runs; only the fallback differs. The expert is privileged (reads "
        "the track): this bounds what a *safe* fallback would give, it is not a deployable "
        "policy. Mean [95% crossed bootstrap CI: training seeds and tracks resampled "
        "independently, bootstrap seed 0]; *paired*: "
        "difference to the same seed's start without a fallback on the same tracks.",
        "",
    ]
    head = [
        "policy",
        "reward",
        "reward - start, paired",
        "violation steps / episode",
        "violation steps - start, paired",
        "episodes with a violation",
        "n",
    ]
    rows = []
    for _, r in summary.iterrows():
        m = r["method"]
        d_r = d_v = ""
        if m in pairs.index:
            diff = pairs.loc[m].rename(lambda c: c.removeprefix("d_"))
            d_r, d_v = fmt_ci(diff, "reward"), fmt_ci(diff, "violation_steps")
        rows.append(
            [
                LABELS[m],
                fmt_ci(r, "reward", 0),
                d_r,
                fmt_ci(r, "violation_steps"),
                d_v,
                f"{int(r['episodes_beyond'])} / {int(r['n_episodes'])}",
                r["n"],
            ]
        )
    lines += [
        markdown_table(rows, head),
        "",
        "Provenance:",
        "",
        f"* command: `{meta['command']}`",
        f"* git revision: `{meta['git_revision']}`, created {meta['created_utc']}",
        "",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    from safe_bc.bc import load_checkpoint
    from safe_bc.data.store import load_demonstrations
    from safe_bc.evaluation import EvalConfig, ExpertSource, NetSource
    from safe_bc.improve import ImprovedSource
    from safe_bc.metrics import paired_crossed
    from safe_bc.provenance import run_metadata
    from safe_bc.tasks import task_defaults

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=Path, default=Path("results/improve/carracing"))
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--modes", nargs="+", choices=["both", "ppo"], default=["both"])
    p.add_argument("--episodes", type=int, default=50, help="held-out tracks")
    p.add_argument("--eval-seed", type=int, default=7, help="held-out seed block")
    p.add_argument("--workers", type=int, default=2, help="evaluation actors (0: in-process)")
    p.add_argument("--processes", type=int, default=0, help="> 0: local processes, no Ray")
    p.add_argument("--demos", type=Path, default=Path("data/demos"))
    p.add_argument("--out", type=Path, default=Path("results/improve/carracing/fallback"))
    p.add_argument("--quiet", action="store_true")
    args = p.parse_args(argv)
    command = shlex.join([sys.executable.rsplit("/", 1)[-1], "-m", "scripts.fallback_carracing",
                          *(sys.argv[1:] if argv is None else argv)])  # fmt: skip

    task = task_defaults("carracing")
    expert = ExpertSource(task.expert)
    sources: dict[str, Any] = {"expert": expert}
    for k in args.seeds:
        start = NetSource.from_model(*load_checkpoint(args.runs / "starts" / f"seed{k}"))
        zone = ImprovedSource.from_run(args.runs / "runs" / "both" / f"seed{k}").shield
        sources[f"imitation/{k}"] = start
        sources[f"imitation+expert/{k}"] = ImprovedSource(start, expert, zone)
        for mode in args.modes:
            run = ImprovedSource.from_run(args.runs / "runs" / mode / f"seed{k}")
            sources[f"{mode}/{k}"] = run
            sources[f"{mode}+expert/{k}"] = ImprovedSource(run.improved, expert, zone)

    limits = load_demonstrations(args.demos).limits
    cfg = EvalConfig(episodes=args.episodes, workers=args.workers, seed=args.eval_seed,
                     env=task.env)  # fmt: skip
    raw = evaluate_cached(sources, cfg, limits, args.runs / "evaluations",
                          processes=args.processes, progress=not args.quiet)  # fmt: skip
    episodes = split_policy(raw)
    metrics = ["reward", "violation_steps"]
    order = [m for m in LABELS if m in set(episodes["method"])]
    summary = summary_table(episodes, metrics, order, len(args.seeds), args.episodes)
    agents = episodes[episodes["method"] != "expert"]
    paired = paired_crossed(agents, "imitation", metrics, by="method", seed=0)
    meta = run_metadata(episodes=args.episodes, eval_seed=args.eval_seed,
                        train_seeds=args.seeds, runs=str(args.runs), modes=args.modes)  # fmt: skip
    meta["command"] = command
    text = markdown(summary, paired, meta)
    tables = {"episodes": episodes, "summary": summary, "paired": paired}
    write_outputs(args.out, tables, meta, text, markdown_name="fallback.md")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
