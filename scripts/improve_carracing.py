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

from safe_bc.improve import HISTORY, ImproveConfig, LocalEnvs
from safe_bc.report import fmt_ci, markdown_table
from scripts.eval_cache import cache_path, evaluate_cached
from scripts.improve_rehab import MODES, run_modes, split_policy, write_outputs

LABELS = {
    "expert": "expert (scripted, privileged)",
    "imitation": "safety-imitation start (alpha 0.1)",
    "ppo": "PPO, neither mechanism",
    "shield": "shield only",
    "lagrangian": "Lagrangian only",
    "both": "shield + Lagrangian",
}
START_ALPHA = 0.1
"""Default safety focus of the starts (``safe-bc train --alpha A --seed k``): the best alpha
row of the Table 1 made with the cropped bar; ``--start-alpha`` takes the current Table 1's."""


MODE_COLOURS = {"ppo": "tab:gray", "shield": "tab:blue", "lagrangian": "tab:orange",
                "both": "tab:green"}  # fmt: skip
SEED_STYLES = ["-", "--", ":", "-."]


def plot_curves(history: pd.DataFrame, refs: dict[str, float], path: Path) -> Path:
    """Training and validation reward, violations and the multiplier vs env steps: colour =
    mode, line style = training seed; dashed black / gray lines: the expert's and the starts'
    mean held-out reward."""
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    from safe_bc.plots import save_figure

    panels = [
        ("train_reward", "training reward (stochastic policy)"),
        ("val_reward", "validation reward (mean action, 4 tracks)"),
        ("train_violation_steps", "training: steps beyond d_s / episode"),
        ("lambda", "Lagrange multiplier"),
    ]
    seeds = sorted(history["train_seed"].unique())
    fig, axes = plt.subplots(2, 2, figsize=(11, 7))
    for ax, (col, title) in zip(axes.flat, panels, strict=True):
        for (mode, seed), df in history.groupby(["mode", "train_seed"], sort=False):
            df = df.dropna(subset=[col])
            ax.plot(df["env_steps"] / 1e3, df[col], lw=1.1, color=MODE_COLOURS[mode],
                    ls=SEED_STYLES[seeds.index(seed) % len(SEED_STYLES)])  # fmt: skip
        if col == "val_reward":
            for name, value in refs.items():
                ax.axhline(value, ls="--", lw=1, color="k" if name == "expert" else "0.6")
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("env steps (thousands)")
    handles = [Line2D([], [], color=c, label=LABELS[m]) for m, c in MODE_COLOURS.items()
               if m in set(history["mode"])]  # fmt: skip
    handles += [Line2D([], [], color="k", ls=SEED_STYLES[i % len(SEED_STYLES)],
                       label=f"training seed {s}") for i, s in enumerate(seeds)]  # fmt: skip
    handles += [
        Line2D([], [], color="k", ls="--", lw=1, label="expert (held-out mean)"),
        Line2D([], [], color="0.6", ls="--", lw=1, label="starts (held-out mean)"),
    ]
    fig.legend(handles=handles, loc="lower center", ncol=4, fontsize=7, frameon=False)
    fig.suptitle("CarRacing improvement learning curves", fontsize=9)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    return save_figure(fig, path)


def summary_table(
    episodes: pd.DataFrame, metrics: list[str], order: list[str], n_seeds: int, n_tracks: int
) -> pd.DataFrame:
    """One row per method in ``order``: :func:`safe_bc.metrics.summarize_crossed` over training
    seeds x tracks (every seed on the same tracks: a crossed design), plus ``episodes_beyond``
    (episodes with a step beyond d_s), ``n_episodes`` and ``n`` (``seeds x tracks``; the
    expert, trained once, ``1 x tracks``)."""
    from safe_bc.metrics import summarize_crossed

    summary = summarize_crossed(episodes, ["method"], metrics, seed=0)
    summary = summary.set_index("method").loc[order].reset_index()
    by = episodes.groupby("method")
    beyond = by["violation_steps"].apply(lambda v: int((v > 0).sum()))
    summary["episodes_beyond"] = summary["method"].map(beyond)
    summary["n_episodes"] = summary["method"].map(by.size())
    summary["n"] = [f"{1 if m == 'expert' else n_seeds}x{n_tracks}" for m in summary["method"]]
    return summary


def _machines(metas: list[dict[str, Any]]) -> str:
    """``"<machine> (<cpus> CPUs, python <v>): <n>"`` per distinct machine in ``metas``."""
    count = collections.Counter(
        f"{m['machine']} ({m.get('cpus', '?')} CPUs, python {m['python']})" for m in metas
    )
    return "; ".join(f"{machine}: {n}" for machine, n in count.items())


def markdown(
    summary: pd.DataFrame, paired: pd.DataFrame, per_seed: pd.DataFrame, meta: dict[str, Any]
) -> str:
    """The result table, the per-seed table and the provenance."""
    lines = [
        "# Beyond the expert: constrained improvement on CarRacing",
        "",
        f"{meta['episodes']} fresh held-out tracks (evaluation seed {meta['eval_seed']}, env "
        f"seeds {meta['env_seeds'][0]}...{meta['env_seeds'][-1]}), the same for every policy; "
        f"training seeds {meta['train_seeds']}. Mean [95% crossed bootstrap CI: training seeds "
        "and tracks resampled independently, bootstrap seed 0; for the expert, trained once, "
        "tracks only]. *Paired*: "
        "the difference to the same seed's start on the same tracks. Limits d_s (the expert's "
        f"worst costs in {meta['demos']}, px): {meta['limits_text']}.",
        "",
    ]
    head = [
        "method",
        "reward",
        "reward - start, paired",
        "safety mean (px)",
        "violation steps / episode",
        "violation steps - start, paired",
        "episodes with a violation",
        "off-road steps / episode",
        "n",
        "compute / run",
    ]
    rows = []
    pairs = paired.set_index("method") if len(paired) else pd.DataFrame()
    for _, r in summary.iterrows():
        m = r["method"]
        d_reward = d_viol = ""
        if m in pairs.index:
            diff = pairs.loc[m].rename(lambda c: c.removeprefix("d_"))
            d_reward, d_viol = fmt_ci(diff, "reward"), fmt_ci(diff, "violation_steps")
        minutes = f"{r['minutes']:.0f} min" if np.isfinite(r["minutes"]) else ""
        rows.append(
            [
                LABELS[m],
                fmt_ci(r, "reward", 0),
                d_reward,
                fmt_ci(r, "safety_mean", 2),
                fmt_ci(r, "violation_steps"),
                d_viol,
                f"{int(r['episodes_beyond'])} / {int(r['n_episodes'])}",
                fmt_ci(r, "offroad_steps"),
                r["n"],
                minutes,
            ]
        )
    seeds = list(per_seed.columns)
    lines += [
        markdown_table(rows, head),
        "",
        "Per training seed: mean reward on the tracks (episodes with a violation of "
        f"{meta['episodes']}).",
        "",
        markdown_table(
            [[LABELS[m], *row] for m, row in per_seed.iterrows()],
            ["method", *(f"seed {k}" for k in seeds)],
        ),
    ]
    lines += [
        "",
        "*compute / run*: wall time of one improvement run (training rollouts, PPO updates and "
        "validation), 1 torch thread, mean over training seeds. Runs made on: "
        f"{meta['run_machines']}. Evaluations made on: {meta['eval_machines']}.",
        "",
        "![learning curves](learning_curves.png)",
        "",
        "Provenance:",
        "",
        f"* command: `{meta['command']}`",
        f"* git revision: `{meta['git_revision']}`, created {meta['created_utc']}",
        f"* starts: `safe-bc train --demos {meta['demos']} --alpha {meta['start_alpha']} --seed k`",
        f"* improvement config (per mode, `seed` = k): `{meta['config']}`",
        "",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    from safe_bc.data.store import load_demonstrations, read_table
    from safe_bc.evaluation import EvalConfig, ExpertSource
    from safe_bc.metrics import paired_crossed
    from safe_bc.provenance import run_metadata
    from safe_bc.tasks import task_defaults

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument(
        "--start-alpha",
        type=float,
        default=START_ALPHA,
        help="safety focus of the starts (safe-bc train --alpha), e.g. Table 1's best",
    )
    p.add_argument("--modes", nargs="+", choices=list(MODES), default=list(MODES))
    p.add_argument("--iterations", type=int, default=20)
    p.add_argument("--episodes-per-iter", type=int, default=4)
    p.add_argument("--val-episodes", type=int, default=4)
    p.add_argument("--cost-margin", type=float, default=1.0, help="px inside d_s")
    p.add_argument("--init-std", type=float, default=ImproveConfig.init_std,
                   help="the policy's initial action noise (std, before its learned "
                   "log-std moves it)")  # fmt: skip
    p.add_argument("--lambda-lr", type=float, default=ImproveConfig.lambda_lr,
                   help="multiplier step per iteration and unit of episode cost")  # fmt: skip
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
        lambda_lr=args.lambda_lr,
        init_std=args.init_std,
        checkpoint_every=1,
    )
    demos = load_demonstrations(args.demos)
    limits = demos.limits
    start_args = ["--alpha", str(args.start_alpha)]

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
                                   start_args=start_args, on_iteration=report, envs=envs,
                                   processes=args.processes)  # fmt: skip
    sources: dict[str, Any] = {"expert": ExpertSource(task.expert), **trained}

    cfg = EvalConfig(episodes=args.episodes, workers=args.workers, seed=args.eval_seed,
                     env=task.env)  # fmt: skip
    raw = evaluate_cached(sources, cfg, limits, args.out / "evaluations",
                          processes=args.processes, progress=not args.quiet)  # fmt: skip
    episodes = split_policy(raw)

    metrics = ["reward", "safety_mean", "violation_steps", "any_violation", "offroad_steps"]
    order = ["expert", "imitation", *args.modes]
    summary = summary_table(episodes, metrics, order, len(args.seeds), args.episodes)
    history = pd.concat(histories, ignore_index=True)
    minutes = history.groupby(["mode", "train_seed"])["seconds"].sum().groupby("mode").mean() / 60
    summary["minutes"] = summary["method"].map(minutes).astype(float)
    run_machines = _machines([read_table(args.out / "runs" / mode / f"seed{k}" / HISTORY)[1]
                              for mode in args.modes for k in args.seeds])  # fmt: skip
    eval_machines = _machines([read_table(cache_path(args.out / "evaluations", key))[1]
                               for key in sources])  # fmt: skip
    beyond = episodes.assign(beyond=episodes["violation_steps"] > 0)
    cells = beyond[beyond["method"] != "expert"].groupby(["method", "train_seed"])
    per_seed = (cells["reward"].mean().round(0).astype(int).astype(str) + " ("
                + cells["beyond"].sum().astype(str) + ")").unstack()  # fmt: skip
    per_seed = per_seed.loc[[m for m in order if m in per_seed.index]]

    # each improved agent against its own start, same (training seed, track) cells
    agents = episodes[episodes["method"] != "expert"]
    paired = paired_crossed(agents, "imitation", ["reward", "violation_steps"],
                            by="method", seed=0)  # fmt: skip
    means = episodes.groupby("method")["reward"].mean()
    plot_curves(history, {"expert": means["expert"], "imitation": means["imitation"]},
                args.out / "learning_curves.png")  # fmt: skip

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
        start_args=start_args,
        run_machines=run_machines,
        eval_machines=eval_machines,
        processes=args.processes,
    )
    meta["command"] = command
    meta["start_alpha"] = args.start_alpha
    text = markdown(summary, paired, per_seed, meta)
    tables = {"episodes": episodes, "summary": summary, "paired": paired, "history": history}
    write_outputs(args.out, tables, meta, text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
