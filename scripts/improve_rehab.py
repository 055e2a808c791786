"""Beyond the expert on the rehabilitation pathway: starts, improvement runs, held-out table.

Usage::

    .venv/bin/python -m scripts.improve_rehab                      # 3 seeds, 200 patients
    .venv/bin/python -m scripts.improve_rehab --seeds 0 --episodes 20 --iterations 20 \\
        --out /tmp/improve_smoke                                    # a quick look

For each training seed ``k``: a safety-imitation start (``safe-bc train --alpha 0.5 --seed
k``, reused when present), then one :func:`safe_bc.improve.improve` run per mode (``ppo``:
neither mechanism, ``shield``, ``lagrangian``, ``both``), each resumable. Then every policy
(the guideline clinician, each start, each improved agent) goes through the one evaluation
path, :func:`safe_bc.distributed.evaluate.evaluate`, on the same fresh held-out patients.

The evaluation path scores the state *before* each session, so the outcome of a
programme's last session is never scored there; each (policy, patient) is therefore
replayed once more (same seeds, deterministic policies, so the same trajectory: the rewards
are checked to agree) to count every session whose outcome went beyond ``d_s``, the last
one included (``violating_sessions``).

Writes ``OUT/episodes.parquet`` (one row per policy and patient), ``OUT/summary.parquet``,
``OUT/paired.parquet`` (differences to the guideline on the same patients),
``OUT/history.parquet`` (learning curves), ``OUT/improve.md`` and
``OUT/learning_curves.png``; runs live in ``OUT/runs/<mode>/seed<k>/``.
"""

from __future__ import annotations

import argparse
import multiprocessing
import shlex
import sys
from collections.abc import Callable
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from safe_bc.improve import (
    EnvGroupFactory,
    ImproveConfig,
    ImprovedSource,
    LocalEnvs,
    improve,
    validation_seeds,
)
from safe_bc.report import fmt_ci, markdown_table

MODES = {"ppo": (False, False), "shield": (True, False), "lagrangian": (False, True),
         "both": (True, True)}  # fmt: skip
"""Mode -> ``(shield, lagrangian)``."""
LABELS = {
    "expert": "guideline clinician (expert)",
    "imitation": "safety-imitation start",
    "ppo": "PPO, neither mechanism",
    "shield": "shield only",
    "lagrangian": "Lagrangian only",
    "both": "shield + Lagrangian",
}
START_ARGS = ["--alpha", "0.5"]
"""How the starts are trained (with ``--seed k``; the rest are ``safe-bc train`` defaults)."""
SHIELD_EPS = 0.1
"""Width of the shield's critical zone on the rehab pathway (``ImproveConfig.eps``; the
start's selection eps, 0.05, when unset): the margin sweep's choice, shield + Lagrangian with
``cost_margin`` 0.05 and this zone (``results/improve/rehab/sweep/margin_sweep.md``)."""


def ensure_start(demos: Path, out: Path, seed: int, start_args: list[str] = START_ARGS) -> Path:
    """The safety-imitation start of ``seed`` (``safe-bc train`` with ``start_args``, unless
    ``out`` holds one)."""
    import json
    from dataclasses import asdict

    from safe_bc.bc import PreprocessConfig
    from safe_bc.cli import main

    if (out / "config.json").exists():  # reuse only a start trained as asked
        stored = json.loads((out / "config.json").read_text())
        run = stored.get("extra", {}).get("run", {})
        i = start_args.index("--alpha") + 1 if "--alpha" in start_args else None
        want = None if i is None else float(start_args[i])
        have = run.get("selection", {}).get("alpha")
        pixels = len(stored.get("spec", {}).get("obs_shape", ())) == 3  # preprocessing matters
        pre = run.get("bc", {}).get("preprocess") if pixels else None
        if (want is not None and have != want) or pre not in (None, asdict(PreprocessConfig())):
            raise SystemExit(
                f"{out} holds a start trained with alpha {have} and preprocessing {pre}, not "
                f"the {start_args} and default preprocessing asked for: remove it to retrain"
            )
    else:
        argv = ["train", "--demos", str(demos), "--out", str(out), *start_args,
                "--seed", str(seed), "--quiet"]  # fmt: skip
        if main(argv) != 0:
            raise SystemExit(f"training the start {out} failed")
    return out


def run_modes(
    demos: Path,
    out: Path,
    seeds: list[int],
    modes: list[str],
    base: ImproveConfig,
    command: str,
    *,
    start_args: list[str] = START_ARGS,
    on_iteration: Callable[[str, int, dict[str, float]], None] | None = None,
    envs: EnvGroupFactory = LocalEnvs,
    processes: int = 0,
) -> tuple[dict[str, Any], list[pd.DataFrame]]:
    """Per training seed ``k`` its start (``OUT/starts/seed<k>``) and one resumable improvement
    run per mode (``OUT/runs/<mode>/seed<k>``). Returns the policy sources
    (``imitation/<k>``, ``<mode>/<k>``) and each run's history (``mode``, ``train_seed``).

    ``processes`` > 0 runs the improvement runs in that many local processes first (1 torch
    thread each, envs in-process, started with ``spawn``: a forked child of a process that
    has used torch can hang; progress lines instead of ``on_iteration``); the runs are
    then picked up as finished.
    """
    from safe_bc.bc import load_checkpoint
    from safe_bc.evaluation import NetSource

    sources: dict[str, Any] = {}
    jobs = []
    for k in seeds:
        start = ensure_start(demos, out / "starts" / f"seed{k}", k, start_args)
        sources[f"imitation/{k}"] = NetSource.from_model(*load_checkpoint(start))
        for mode in modes:
            shield, lagrangian = MODES[mode]
            cfg = replace(base, shield=shield, lagrangian=lagrangian, seed=k)
            jobs.append((mode, k, start, out / "runs" / mode / f"seed{k}", cfg))
    if processes > 0:
        ctx = multiprocessing.get_context("spawn")
        with ctx.Pool(min(processes, len(jobs))) as pool:
            waiting = [pool.apply_async(_run_quietly, (start, run, cfg, command, mode, k,
                                                       on_iteration is not None))
                       for mode, k, start, run, cfg in jobs]  # fmt: skip
            for job in waiting:
                job.get()
    histories = []
    for mode, k, start, run, cfg in jobs:
        report = None if on_iteration is None else partial(on_iteration, mode, k)
        done = improve(start, run, cfg, metadata={"command": command}, on_iteration=report,
                       envs=envs)  # fmt: skip
        histories.append(done.history.assign(mode=mode, train_seed=k))
        sources[f"{mode}/{k}"] = ImprovedSource.from_run(run)
    return sources, histories


def _run_quietly(
    start: Path, run: Path, cfg: ImproveConfig, command: str, mode: str, k: int, show: bool
) -> None:
    """One improvement run in a pool process, with a line of progress per iteration."""

    def line(row: dict[str, float]) -> None:
        print(f"{mode} seed {k} iteration {int(row['iteration'])}: train reward "
              f"{row['train_reward']:.2f}, violation steps {row['train_violation_steps']:.2f}, "
              f"lambda {row['lambda']:.2f}, {row['seconds']:.0f} s", flush=True)  # fmt: skip

    improve(start, run, cfg, metadata={"command": command}, on_iteration=line if show else None)


def split_policy(episodes: pd.DataFrame) -> pd.DataFrame:
    """``episodes`` with ``method`` and ``train_seed`` (-1: untrained) from ``policy`` keys
    ``<method>[/<seed>]``."""
    split = episodes["policy"].str.split("/", expand=True)
    seeds = pd.to_numeric(split[1]).fillna(-1).astype(int) if 1 in split else -1
    return episodes.assign(method=split[0], train_seed=seeds)


def write_outputs(
    out: Path,
    tables: dict[str, pd.DataFrame],
    meta: dict[str, Any],
    text: str,
    markdown_name: str = "improve.md",
) -> None:
    """``OUT/<name>.parquet`` for every table (with ``meta``) and ``OUT/<markdown_name>``."""
    from safe_bc.data.store import write_table_atomic, write_text_atomic

    out.mkdir(parents=True, exist_ok=True)
    for name, table in tables.items():
        write_table_atomic(out / f"{name}.parquet", table, meta)
    write_text_atomic(out / markdown_name, text)


def session_outcomes(
    source: Any, env_config: Any, seeds: list[int], limits: np.ndarray
) -> pd.DataFrame:
    """Replay ``source`` on ``seeds`` as the evaluation path does; per episode its reward and
    the number of sessions whose outcome is beyond ``limits`` (all sessions, the last too)."""
    from safe_bc.envs import make_env
    from safe_bc.metrics import violations

    env, policy = make_env(env_config), source.build()
    rows = []
    for seed in seeds:
        obs, _ = env.reset(seed=seed)
        policy.reset(env, np.random.default_rng(seed))
        total, beyond, last, done = 0.0, 0, 0.0, False
        while not done:
            obs, reward, terminated, truncated, info = env.step(policy.act(obs, env))
            total += reward
            last = float(violations(np.asarray(info["cost"])[None], limits)[0])
            beyond += int(last)
            done = terminated or truncated
        rows.append({"env_seed": seed, "replay_reward": total, "violating_sessions": beyond,
                     "last_session_violation": last})  # fmt: skip
    env.close()
    return pd.DataFrame(rows)


def validation_reference(source: Any, env_config: Any, limits: np.ndarray, n: int) -> float:
    """Mean reward of ``source`` on the runs' ``n`` validation patients (curve reference)."""
    return float(session_outcomes(source, env_config, validation_seeds(n), limits)[
        "replay_reward"].mean())  # fmt: skip


def plot_curves(history: pd.DataFrame, refs: dict[str, float], path: Path) -> Path:
    """Validation reward and violations, training violations and the multiplier vs env steps
    (mean over training seeds, band: min to max)."""
    import matplotlib.pyplot as plt

    from safe_bc.plots import save_figure

    panels = [
        ("val_reward", "validation reward (capacity gain, points)"),
        ("val_violation_steps", "validation: sessions beyond d_s / patient"),
        ("train_violation_steps", "training (stochastic): sessions beyond d_s / episode"),
        ("lambda", "Lagrange multiplier"),
    ]
    fig, axes = plt.subplots(2, 2, figsize=(11, 7))
    for ax, (col, title) in zip(axes.flat, panels, strict=True):
        for mode, df in history.groupby("mode", sort=False):
            df = df.dropna(subset=[col])
            if col.startswith("train_"):  # smooth the noisy per-iteration values
                df = df.assign(**{col: df.groupby("train_seed")[col].transform(
                    lambda s: s.rolling(10, min_periods=1).mean())})  # fmt: skip
            g = df.groupby("env_steps")[col]
            x = g.mean().index.to_numpy() / 1e3
            ax.plot(x, g.mean().to_numpy(), lw=1.2, label=LABELS[mode])
            ax.fill_between(x, g.min().to_numpy(), g.max().to_numpy(), alpha=0.15)
        if col == "val_reward":
            for name, value in refs.items():
                ax.axhline(value, ls="--", lw=1, color="k" if name == "expert" else "gray",
                           label=LABELS[name])  # fmt: skip
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("env steps (thousands)")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle("learning curves: mean over training seeds, band min-max", fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path)


def markdown(summary: pd.DataFrame, paired: pd.DataFrame, meta: dict[str, Any]) -> str:
    """The result table with its provenance."""
    lines = [
        "# Beyond the expert: constrained improvement on the rehabilitation pathway",
        "",
        f"{meta['episodes']} fresh held-out patients (evaluation seed {meta['eval_seed']}, "
        f"env seeds {meta['env_seeds'][0]}...{meta['env_seeds'][-1]}), the same for every "
        f"policy; {len(meta['train_seeds'])} training seeds {meta['train_seeds']}. Mean "
        "[95% crossed bootstrap CI: training seeds and patients resampled independently, "
        "bootstrap seed 0]. Limits d_s "
        f"(worst guideline cost in {meta['demos']}): {meta['limits_text']}. The Lagrangian "
        f"charges sessions beyond d_s - {meta['config']['cost_margin']} (`cost_margin`: a "
        "safety margin inside d_s) and the shield acts within "
        f"{meta['config']['eps']} of d_s (`eps`), both chosen on selection patients disjoint "
        "from these, see [sweep/margin_sweep.md](sweep/margin_sweep.md).",
        "",
    ]
    head = [
        "method",
        "capacity gain (reward)",
        "gain - guideline, paired",
        "safety mean",
        "sessions beyond d_s / patient",
        "patients with a session beyond d_s",
        "of which last session",
        "eval-path violation steps",
        "n",
        "compute / run",
    ]
    rows = []
    pairs = paired.set_index("method") if len(paired) else pd.DataFrame()
    for _, r in summary.iterrows():
        m = r["method"]
        d = ""
        if m in pairs.index:
            d = fmt_ci(pairs.loc[m].rename(lambda c: c.removeprefix("d_")), "reward", 2)
        minutes = f"{r['minutes']:.1f} min" if np.isfinite(r["minutes"]) else ""
        rows.append(
            [
                LABELS[m],
                fmt_ci(r, "reward", 2),
                d,
                fmt_ci(r, "safety_mean", 3),
                fmt_ci(r, "violating_sessions", 3),
                f"{int(r['patients_beyond'])} / {int(r['n_episodes'])}",
                int(r["last_beyond"]),
                int(r["eval_path_violation_steps"]),
                r["n"],
                minutes,
            ]
        )
    lines += [
        markdown_table(rows, head),
        "",
        "Columns: *sessions beyond d_s* counts every session whose outcome (peak heart rate, "
        "fatigue or peak systolic pressure) exceeded the worst the guideline reached on its "
        "demonstrations, the programme's last session included (a replay of the same "
        "episodes); *eval-path violation steps* is the evaluation path's own count (it scores "
        "the state before each session, so it cannot see the last outcome). *compute / run*: "
        "wall time of one improvement run on 2 shared CPU cores (1 torch thread, nice 19).",
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
    from safe_bc.distributed.evaluate import evaluate
    from safe_bc.evaluation import EvalConfig, ExpertSource
    from safe_bc.metrics import paired_crossed, summarize_crossed
    from safe_bc.provenance import run_metadata
    from safe_bc.tasks import task_defaults

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--modes", nargs="+", choices=list(MODES),
                   default=["shield", "lagrangian", "both"])  # fmt: skip
    p.add_argument("--episodes", type=int, default=200, help="held-out patients")
    p.add_argument("--eval-seed", type=int, default=5, help="held-out seed block")
    p.add_argument("--iterations", type=int, default=None, help="override the config's")
    p.add_argument("--demos", type=Path, default=Path("data/rehab_demos"))
    p.add_argument("--out", type=Path, default=Path("results/improve/rehab"))
    p.add_argument(
        "--processes",
        type=int,
        default=0,
        help="run the improvement runs in N local processes (0: one after another)",
    )
    p.add_argument("--quiet", action="store_true")
    args = p.parse_args(argv)
    command = shlex.join([sys.executable.rsplit("/", 1)[-1], "-m", "scripts.improve_rehab",
                          *(sys.argv[1:] if argv is None else argv)])  # fmt: skip

    task = task_defaults("rehab")
    base = ImproveConfig(eps=SHIELD_EPS)
    if args.iterations is not None:
        base = replace(base, iterations=args.iterations)
    demos = load_demonstrations(args.demos)
    limits = demos.limits

    def report(mode: str, k: int, row: dict[str, float]) -> None:
        if not args.quiet and row["iteration"] == base.iterations:
            print(f"{mode} seed {k}: {int(row['iteration'])} iterations", flush=True)

    trained, histories = run_modes(args.demos, args.out, args.seeds, args.modes, base, command,
                                   on_iteration=report, processes=args.processes)  # fmt: skip
    sources: dict[str, Any] = {"expert": ExpertSource(task.expert), **trained}
    start = args.out / "starts" / f"seed{args.seeds[-1]}"

    eps = read_table(start / "selection.parquet")[1]["config"]["eps"]  # every start's
    cfg = EvalConfig(episodes=args.episodes, workers=0, seed=args.eval_seed, env=task.env,
                     eps=eps)  # fmt: skip
    result = evaluate(sources, cfg, limits, progress=not args.quiet)
    episodes = split_policy(result.episodes)
    replays = []
    for key, source in sources.items():
        replays.append(session_outcomes(source, task.env, cfg.seeds(), limits).assign(policy=key))
    episodes = episodes.merge(pd.concat(replays), on=["policy", "env_seed"], validate="1:1")
    if not np.allclose(episodes["reward"], episodes["replay_reward"], atol=1e-4):
        raise RuntimeError("the replay did not reproduce the evaluated episodes")
    episodes["any_violating_session"] = (episodes["violating_sessions"] > 0).astype(float)

    metrics = ["reward", "safety_mean", "violation_steps", "violating_sessions",
               "any_violating_session", "worst_excursion"]  # fmt: skip
    summary = summarize_crossed(episodes, ["method"], metrics, seed=0)
    order = ["expert", "imitation", *args.modes]
    summary = summary.set_index("method").loc[order].reset_index()
    by = episodes.groupby("method")
    summary["patients_beyond"] = summary["method"].map(by["any_violating_session"].sum())
    summary["last_beyond"] = summary["method"].map(by["last_session_violation"].sum())
    summary["eval_path_violation_steps"] = summary["method"].map(by["violation_steps"].sum())
    summary["n"] = [
        f"{1 if m == 'expert' else len(args.seeds)}x{args.episodes}" for m in summary["method"]
    ]
    history = pd.concat(histories, ignore_index=True)
    minutes = history.groupby(["mode", "train_seed"])["seconds"].sum().groupby("mode").mean() / 60
    summary["minutes"] = summary["method"].map(minutes).astype(float)

    # the guideline is not trained: its rows pair with every training seed's on each patient
    expert = episodes[episodes["method"] == "expert"]
    paired_rows = [expert.assign(train_seed=k) for k in args.seeds]
    paired_rows.append(episodes[episodes["method"] != "expert"])
    paired = paired_crossed(pd.concat(paired_rows), "expert", ["reward", "violating_sessions"],
                            by="method", seed=0)  # fmt: skip

    refs = {"expert": validation_reference(sources["expert"], task.env, limits,
                                           base.eval_episodes)}  # fmt: skip
    refs["imitation"] = float(np.mean([
        validation_reference(sources[f"imitation/{k}"], task.env, limits, base.eval_episodes)
        for k in args.seeds]))  # fmt: skip
    plot_curves(history, refs, args.out / "learning_curves.png")

    dims = ", ".join(f"{d} {x:.3f}" for d, x in zip(demos.safety_dims, limits, strict=True))
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
        validation_reference=refs,
    )
    meta["command"] = command
    text = markdown(summary, paired, meta)
    tables = {"episodes": episodes, "summary": summary, "paired": paired, "history": history}
    write_outputs(args.out, tables, meta, text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
