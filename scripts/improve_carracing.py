"""Beyond the expert on CarRacing: constrained improvement from pixels, 3 seeds x 4 modes.

Usage::

    .venv/bin/python -m scripts.improve_carracing                     # the committed table
    .venv/bin/python -m scripts.improve_carracing --processes 16 --workers 0   # 16 cores, no Ray
    .venv/bin/python -m scripts.improve_carracing --seeds 0 --modes both --iterations 2 \
        --episodes 4 --out /tmp/improve_cr_smoke                    # a quick look

The starts are the best Table 1 row's recipe (``safe-bc train --alpha 0.1 --seed k``, reused
when present). One :func:`safe_bc.improve.improve` run per mode (``ppo``: neither mechanism,
``shield``, ``lagrangian``, ``both``) and training seed, sized for pixels on small machines:
``--episodes-per-iter`` complete 1000-step episodes per PPO iteration, validation on
``--val-episodes`` tracks every 5 iterations, and a cost margin of 1 px inside d_s. Each
run checkpoints every iteration and resumes when the command is rerun; a finished run is
reused as it is. Runs go one after another (rollout envs in-process, or on
``--rollout-workers`` Ray actors), or with ``--processes N`` side by side in N local
processes. Then the expert, each start and each improved agent go through the one
evaluation path (:func:`safe_bc.distributed.evaluate.evaluate_policies`, per policy cached
in ``OUT/evaluations/``) on the same ``--episodes`` fresh held-out tracks (evaluation seed
block ``--eval-seed``, used by no other command).

Writes ``OUT/episodes.parquet``, ``OUT/summary.parquet``, ``OUT/paired.parquet``
(differences to the start on the same tracks), ``OUT/history.parquet``, ``OUT/improve.md``
and ``OUT/learning_curves.png``; runs live in ``OUT/runs/<mode>/seed<k>/``.
"""

from __future__ import annotations

import argparse
import collections
import shlex
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from safe_bc.improve import ImproveConfig, LocalEnvs
from scripts.eval_cache import evaluate_cached
from scripts.improve_rehab import MODES, run_modes, split_policy, write_outputs

LABELS = {
    "expert": "expert (scripted, privileged)",
    "imitation": "safety-imitation start (alpha 0.1)",
    "ppo": "PPO, neither mechanism",
    "shield": "shield only",
    "lagrangian": "Lagrangian only",
    "both": "shield + Lagrangian",
}
START_ARGS = ["--alpha", "0.1"]
"""How the starts are trained (with ``--seed k``): Table 1's best row."""


def plot_curves(history: pd.DataFrame, path: Path) -> Path:
    """Training and validation reward, violations and the multiplier vs env steps."""
    import matplotlib.pyplot as plt

    from safe_bc.plots import save_figure

    panels = [
        ("train_reward", "training reward (stochastic policy)"),
        ("val_reward", "validation reward (mean action)"),
        ("train_violation_steps", "training: steps beyond d_s / episode"),
        ("lambda", "Lagrange multiplier"),
    ]
    fig, axes = plt.subplots(2, 2, figsize=(11, 7))
    for ax, (col, title) in zip(axes.flat, panels, strict=True):
        for (mode, seed), df in history.groupby(["mode", "train_seed"], sort=False):
            df = df.dropna(subset=[col])
            ax.plot(df["env_steps"] / 1e3, df[col], marker=".", lw=1,
                    label=f"{LABELS[mode]}, seed {seed}")  # fmt: skip
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("env steps (thousands)")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle("CarRacing improvement learning curves", fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path)


def _fmt(row: pd.Series, m: str, digits: int = 1) -> str:
    return f"{row[m]:.{digits}f} [{row[m + '_lo']:.{digits}f}, {row[m + '_hi']:.{digits}f}]"


def markdown(summary: pd.DataFrame, paired: pd.DataFrame, meta: dict[str, Any]) -> str:
    """The result table with its provenance."""
    lines = [
        "# Beyond the expert: constrained improvement on CarRacing",
        "",
        f"{meta['episodes']} fresh held-out tracks (evaluation seed {meta['eval_seed']}, env "
        f"seeds {meta['env_seeds'][0]}...{meta['env_seeds'][-1]}), the same for every policy; "
        f"training seeds {meta['train_seeds']}. Mean [95% bootstrap CI; with one training seed "
        "over tracks only]. Limits d_s (the expert's worst costs in "
        f"{meta['demos']}, px): {meta['limits_text']}.",
        "",
        "| method | reward | reward - start, paired | safety mean (px) | violation steps "
        "/ episode | episodes with a violation | off-road steps / episode | n | "
        "compute / run |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    pairs = paired.set_index("method") if len(paired) else pd.DataFrame()
    for _, r in summary.iterrows():
        m = r["method"]
        d = ""
        if m in pairs.index:
            d = _fmt(pairs.loc[m].rename(lambda c: c.removeprefix("d_")), "reward")
        minutes = f"{r['minutes']:.0f} min" if np.isfinite(r["minutes"]) else ""
        lines.append(
            f"| {LABELS[m]} | {_fmt(r, 'reward', 0)} | {d} | {_fmt(r, 'safety_mean', 2)} | "
            f"{_fmt(r, 'violation_steps')} | {int(r['episodes_beyond'])} / "
            f"{int(r['n_episodes'])} | {_fmt(r, 'offroad_steps')} | {r['n']} | {minutes} |"
        )
    lines += [
        "",
        "*compute / run*: wall time of one improvement run (training rollouts, PPO updates and "
        f"validation), 1 torch thread, mean over training seeds, on {meta['run_machines']}.",
        "",
        "![learning curves](learning_curves.png)",
        "",
        "Provenance:",
        "",
        f"* command: `{meta['command']}`",
        f"* git revision: `{meta['git_revision']}`, created {meta['created_utc']}",
        f"* starts: `safe-bc train --demos {meta['demos']} {' '.join(START_ARGS)} --seed k`",
        f"* improvement config (per mode, `seed` = k): `{meta['config']}`",
        "",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    from safe_bc.data.store import load_demonstrations, read_table
    from safe_bc.evaluation import EvalConfig, ExpertSource
    from safe_bc.metrics import paired_differences, summarize
    from safe_bc.provenance import run_metadata
    from safe_bc.tasks import task_defaults

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--modes", nargs="+", choices=list(MODES), default=list(MODES))
    p.add_argument("--iterations", type=int, default=20)
    p.add_argument("--episodes-per-iter", type=int, default=4)
    p.add_argument("--val-episodes", type=int, default=4)
    p.add_argument("--cost-margin", type=float, default=1.0, help="px inside d_s")
    p.add_argument("--episodes", type=int, default=50, help="held-out tracks")
    p.add_argument("--eval-seed", type=int, default=7, help="held-out seed block")
    p.add_argument("--workers", type=int, default=2, help="evaluation actors (0: in-process)")
    p.add_argument("--rollout-workers", type=int, default=0,
                   help="Ray actors stepping each run's rollout envs (0: in-process; on 2 cores "
                   "in-process is faster, see make bench); the runs are bit-identical either "
                   "way")  # fmt: skip
    p.add_argument("--processes", type=int, default=0,
                   help="> 0: runs and evaluations in this many local processes instead (no "
                   "Ray; a many-core machine), rollout envs in-process")  # fmt: skip
    p.add_argument("--demos", type=Path, default=Path("data/demos"))
    p.add_argument("--out", type=Path, default=Path("results/improve/carracing"))
    p.add_argument("--quiet", action="store_true")
    args = p.parse_args(argv)
    command = shlex.join([sys.executable.rsplit("/", 1)[-1], "-m", "scripts.improve_carracing",
                          *(sys.argv[1:] if argv is None else argv)])  # fmt: skip

    task = task_defaults("carracing")
    base = ImproveConfig(
        iterations=args.iterations,
        episodes_per_iter=args.episodes_per_iter,
        n_envs=args.episodes_per_iter,
        eval_every=5,
        eval_episodes=args.val_episodes,
        cost_margin=args.cost_margin,
        checkpoint_every=1,
    )
    demos = load_demonstrations(args.demos)
    limits = demos.limits

    def report(mode: str, k: int, row: dict[str, float]) -> None:
        if not args.quiet:
            print(f"{mode} seed {k} iteration {int(row['iteration'])}: "
                  f"train reward {row['train_reward']:.0f}, violation steps "
                  f"{row['train_violation_steps']:.0f}, lambda {row['lambda']:.2f}, "
                  f"{row['seconds']:.0f} s", flush=True)  # fmt: skip

    envs = LocalEnvs
    if args.rollout_workers > 0 and args.processes == 0:
        from safe_bc.distributed.envs import ray_envs

        envs = ray_envs(args.rollout_workers)
    trained, histories = run_modes(args.demos, args.out, args.seeds, args.modes, base, command,
                                   start_args=START_ARGS, on_iteration=report, envs=envs,
                                   processes=args.processes)  # fmt: skip
    sources: dict[str, Any] = {"expert": ExpertSource(task.expert), **trained}

    cfg = EvalConfig(episodes=args.episodes, workers=args.workers, seed=args.eval_seed,
                     env=task.env)  # fmt: skip
    raw = evaluate_cached(sources, cfg, limits, args.out / "evaluations",
                          processes=args.processes, progress=not args.quiet)  # fmt: skip
    episodes = split_policy(raw)

    metrics = ["reward", "safety_mean", "violation_steps", "any_violation", "offroad_steps"]
    summary = summarize(episodes, ["method"], metrics, group="train_seed", seed=0)
    order = ["expert", "imitation", *args.modes]
    summary = summary.set_index("method").loc[order].reset_index()
    by = episodes.groupby("method")
    summary["episodes_beyond"] = summary["method"].map(by["violation_steps"].apply(
        lambda s: int((s > 0).sum())))  # fmt: skip
    summary["n_episodes"] = summary["method"].map(by.size())
    summary["n"] = [
        f"{1 if m == 'expert' else len(args.seeds)}x{args.episodes}" for m in summary["method"]
    ]
    history = pd.concat(histories, ignore_index=True)
    minutes = history.groupby(["mode", "train_seed"])["seconds"].sum().groupby("mode").mean() / 60
    summary["minutes"] = summary["method"].map(minutes).astype(float)
    machines = collections.Counter()
    for mode in args.modes:
        for k in args.seeds:
            _, run_meta = read_table(args.out / "runs" / mode / f"seed{k}" / "history.parquet")
            machines[f"{run_meta['machine']} ({run_meta.get('cpus', '?')} CPUs, python "
                     f"{run_meta['python']})"] += 1  # fmt: skip
    run_machines = "; ".join(f"{m}: {n} run(s)" for m, n in machines.items())

    # each improved agent against its own start, same (training seed, track) cells
    agents = episodes[episodes["method"] != "expert"]
    paired = paired_differences(agents, "imitation", ["reward", "violation_steps"],
                                by="method", seed=0)  # fmt: skip
    plot_curves(history, args.out / "learning_curves.png")

    dims = ", ".join(f"{d} {x:.2f}" for d, x in zip(demos.safety_dims, limits, strict=True))
    meta = run_metadata(
        episodes=args.episodes,
        eval_seed=args.eval_seed,
        env_seeds=cfg.seeds(),
        train_seeds=args.seeds,
        modes=args.modes,
        demos=str(args.demos),
        limits=[float(x) for x in limits],
        limits_text=dims,
        config=base.to_dict(),
        start_args=START_ARGS,
        run_machines=run_machines,
        processes=args.processes,
    )
    meta["command"] = command
    text = markdown(summary, paired, meta)
    tables = {"episodes": episodes, "summary": summary, "paired": paired, "history": history}
    write_outputs(args.out, tables, meta, text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
