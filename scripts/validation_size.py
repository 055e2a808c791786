"""How many held-out demonstration episodes a study's validation loss needs, per task.

Usage::

    .venv/bin/python -m scripts.validation_size                 # both tasks
    .venv/bin/python -m scripts.validation_size --task rehab    # one

For each task: plain BC with the study's own base configuration (``tune_jobs/default.py`` for
CarRacing, ``tune_jobs/rehab.py`` for the clinic; :meth:`StudySpec.baseline_config`) trains
on the task's default demonstration set with ``--seeds`` training seeds (one torch thread),
its curve recording the loss on a pool of
``--pool`` validation episodes collected as a study collects its validation set (the task's
collector, collection seed :data:`safe_bc.seeds.VALIDATION_SEED`). Each trained agent's loss
is then read per pool episode, and for ``n`` held-out episodes the loss a study would record
is resampled: ``--draws`` draws of ``n`` episodes with replacement (fixed seed 0), the
row-weighted loss of each draw. ``rel_spread`` is the draws' standard deviation over the
pool's loss (mean over training seeds); ``val_share`` is what the validation passes of ``n``
episodes add to the training loop's time (the pool's measured pass time per row times ``n``
episodes' mean rows).

The rule (:func:`choose`): among the sizes whose validation adds at most :data:`COST_BAR` to
the training time, the fewest episodes whose ``rel_spread`` is at most :data:`SPREAD_BAR`, else
the largest of them. Writes ``validation_size.parquet`` (one row per task and ``n``),
``validation_curves.parquet`` (the agents' training and validation loss at each log point),
``validation_size.md`` and ``validation_size.png`` under ``--out``; the weights are the same
with or without the validation loss, so nothing here changes a result, only what the curves
show and cost.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

SPREAD_BAR = 0.10
"""Largest accepted relative spread of the recorded validation loss (one standard deviation
over the loss on an unlimited set of held-out episodes)."""
COST_BAR = 0.075
"""Largest accepted share the validation passes add to the training loop's time. A timing moves
with the machine's load, so the bar sits between measured sizes, not on one: two runs of this
table on one machine priced one CarRacing track at 4.9% and 5.5% and two at 9.8% and 10.9%,
which a bar at 10% would have split between runs."""
SIZES = (1, 2, 4, 8, 16, 32, 64, 128)
"""Held-out episode counts the table prices (those up to the pool's size)."""
STUDIES = {"carracing": "tune_jobs/default.py", "rehab": "tune_jobs/rehab.py"}
"""The study whose base configuration trains each task's agents."""


def resampled_spread(
    sums: np.ndarray, rows: np.ndarray, n: int, draws: int, rng: np.random.Generator
) -> float:
    """Relative spread of the row-weighted loss of ``n`` episodes drawn with replacement from
    a pool whose episode ``i`` has loss sum ``sums[i]`` over ``rows[i]`` rows.

    >>> rng = np.random.default_rng(0)
    >>> resampled_spread(np.array([1.0, 1.0]), np.array([1, 1]), 1, 100, rng)
    0.0
    """
    pick = rng.integers(0, len(sums), size=(draws, n))
    losses = sums[pick].sum(axis=1) / rows[pick].sum(axis=1)
    return float(losses.std() / (sums.sum() / rows.sum()))


def choose(table: pd.DataFrame) -> pd.Series:
    """Per task, among the sizes whose validation passes add at most :data:`COST_BAR` to the
    training time, the fewest episodes whose ``rel_spread`` is at most :data:`SPREAD_BAR`;
    when none is that precise, the largest of them (the most precise that is affordable);
    when none is affordable, the smallest priced size.

    >>> t = pd.DataFrame({"task": "a", "n_episodes": [1, 2, 4],
    ...                   "rel_spread": [0.3, 0.2, 0.09], "val_share": [0.03, 0.06, 0.2]})
    >>> choose(t).to_dict()
    {'a': 2}
    """
    out = {}
    for task, rows in table.groupby("task", sort=False):
        rows = rows.sort_values("n_episodes")
        within = rows[rows["val_share"] <= COST_BAR]
        precise = within[within["rel_spread"] <= SPREAD_BAR]
        fallback = within.iloc[-1] if len(within) else rows.iloc[0]
        out[task] = int((precise.iloc[0] if len(precise) else fallback)["n_episodes"])
    return pd.Series(out, name="chosen")


def measure(
    task: str, pool: int, seeds: int, draws: int
) -> tuple[pd.DataFrame, pd.DataFrame, dict]:
    """The task's rows of the table, its agents' learning curves (training loss and the loss
    on the whole pool at each log point, per training seed) and the record of its inputs."""
    import torch

    from safe_bc.bc.train import validation_loss
    from safe_bc.data.store import read_demonstrations
    from safe_bc.distributed.collect import ensure_demos
    from safe_bc.methods.experiment import train_run
    from safe_bc.rollout.collect import CollectConfig
    from safe_bc.seeds import VALIDATION_SEED
    from safe_bc.study.spec import load_study
    from safe_bc.study.trial import bounds_for, with_seed

    spec = load_study(Path(__file__).resolve().parents[1] / STUDIES[task])
    collect = spec.collect or CollectConfig.for_task(spec.task())
    ensure_demos(spec.demos, collect, progress=False)
    held = Path(f"{spec.demos}_validation_pool{pool}")
    ensure_demos(held, replace(collect, episodes=pool, seed=VALIDATION_SEED), progress=False)
    demos, demos_record = read_demonstrations(spec.demos)
    val, val_record = read_demonstrations(held)
    episodes = [np.flatnonzero(val.episode_ids == e) for e in np.unique(val.episode_ids)]
    scored = np.array([int(val.scored[r].sum()) for r in episodes])
    torch.set_num_threads(1)
    run = spec.baseline_config(spec.run_config({}, num_threads=1))
    spreads, shares, losses, curves = {}, {}, [], []
    for s in range(seeds):
        cfg = with_seed(run, run.bc.train.seed + s)
        result, _ = train_run(demos, cfg, action_bounds=bounds_for(spec.demos), validation=val)
        per_row = result.val_seconds / (len(result.log_steps) * scored.sum())
        curves.append(result.curve().assign(task=task, train_seed=cfg.bc.train.seed))
        sums = np.array(
            [validation_loss(result.model, val.take(r), cfg.bc.train) * k
             for r, k in zip(episodes, scored, strict=True)]
        )  # fmt: skip
        losses.append(float(sums.sum() / scored.sum()))
        rng = np.random.default_rng(0)
        for n in (n for n in SIZES if n <= pool):
            spreads.setdefault(n, []).append(resampled_spread(sums, scored, n, draws, rng))
            cost = per_row * len(result.log_steps) * n * scored.mean()
            shares.setdefault(n, []).append(cost / result.seconds)
    rows = pd.DataFrame(
        {
            "task": task,
            "n_episodes": list(spreads),
            "rel_spread": [float(np.mean(v)) for v in spreads.values()],
            "rel_spread_max": [float(np.max(v)) for v in spreads.values()],
            "val_share": [float(np.mean(v)) for v in shares.values()],
            "rows_per_episode": float(scored.mean()),
            "pool_loss": float(np.mean(losses)),
            "train_seeds": seeds,
            "pool": pool,
            "draws": draws,
        }
    )
    inputs = {"demos": demos_record, "validation_pool": val_record, "study": STUDIES[task]}
    return rows, pd.concat(curves, ignore_index=True), inputs


def figure(table: pd.DataFrame, curves: pd.DataFrame, chosen: pd.Series, path: Path) -> Path:
    """Per task: the agents' training and validation loss against batches (top), and the
    recorded loss's relative spread and the training time it adds against the held-out
    episodes, the bars and the choice marked (bottom)."""
    import matplotlib.pyplot as plt

    from safe_bc.plots import save_figure

    tasks = list(dict.fromkeys(table["task"]))
    fig, axes = plt.subplots(2, len(tasks), figsize=(5.2 * len(tasks), 7.4), squeeze=False)
    for j, task in enumerate(tasks):
        top, low = axes[0, j], axes[1, j]
        for k, (seed, c) in enumerate(curves[curves["task"] == task].groupby("train_seed")):
            colour = f"C{k}"
            top.plot(c["batch"], c["train_loss"], color=colour, lw=1, label=f"seed {seed} train")
            top.plot(c["batch"], c["val_loss"], color=colour, lw=1, ls="--",
                     label=f"seed {seed} validation")  # fmt: skip
        pool = int(table.loc[table["task"] == task, "pool"].iloc[0])
        top.set(title=f"{task}: BC loss (validation: {pool} held-out episodes)", yscale="log",
                xlabel="batch", ylabel="loss (weighted squared error)")  # fmt: skip
        top.legend(fontsize=7, ncol=2)
        rows = table[table["task"] == task]
        low.plot(rows["n_episodes"], 100 * rows["rel_spread"], "o-", label="loss spread (1 sd)")
        low.plot(rows["n_episodes"], 100 * rows["val_share"], "s-", label="added training time")
        low.axhline(100 * SPREAD_BAR, color="C0", ls=":", lw=1, label="spread bar")
        low.axhline(100 * COST_BAR, color="C1", ls=":", lw=1, label="time bar")
        low.axvline(chosen[task], color="k", lw=1, ls="--", label=f"chosen: {chosen[task]}")
        low.set(xscale="log", xlabel="held-out episodes", ylabel="% of the loss / of training",
                title=f"{task}: {int(rows['train_seeds'].iloc[0])} training seeds")  # fmt: skip
        low.set_xticks(list(rows["n_episodes"]), [str(n) for n in rows["n_episodes"]])
        low.minorticks_off()
        low.legend(fontsize=7)
    fig.tight_layout()
    return save_figure(fig, path)


def made_by(meta: dict) -> str:
    """The Markdown's last line, from the table's metadata: the command and the code revision."""
    return f"{meta['command']}, code {meta.get('git_revision', '?')}"


COLUMNS = ("episodes", "rel. spread (mean)", "rel. spread (max over seeds)", "added to training")
"""The Markdown table's columns, one row per priced size."""


def markdown(table: pd.DataFrame, chosen: pd.Series, source: str) -> str:
    """The table as Markdown with the rule's choice per task."""
    from safe_bc.report import markdown_table

    lines = [
        "# Validation episodes per task",
        "",
        f"The rule: among the sizes whose validation passes add at most {COST_BAR:.1%} to the "
        f"training loop's time, the fewest held-out episodes whose recorded validation loss "
        f"spreads by at most {SPREAD_BAR:.0%} (one sd, relative to the loss on the whole pool); "
        "when none is that precise, the largest of them.",
        "",
    ]
    for task, rows in table.groupby("task", sort=False):
        first = rows.iloc[0]
        lines += [
            f"## {task}: {int(chosen[task])} episode(s)",
            "",
            f"{int(first['train_seeds'])} training seeds, a pool of {int(first['pool'])} "
            f"episodes ({first['rows_per_episode']:.0f} scored rows each on average), "
            f"{int(first['draws'])} draws per size.",
            "",
        ]
        cells = [
            [
                int(r.n_episodes),
                f"{r.rel_spread:.1%}",
                f"{r.rel_spread_max:.1%}",
                f"{r.val_share:.1%}",
            ]
            for r in rows.itertuples()
        ]
        lines.append(markdown_table(cells, COLUMNS))
        lines.append("")
    lines.append(f"Made by `{source}`.")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    from safe_bc.data.provenance import run_metadata
    from safe_bc.data.store import write_table_atomic

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--task", choices=sorted(STUDIES), action="append")
    ap.add_argument(
        "--pool", type=int, default=None, help="episodes in the pool (8 car, 128 rehab)"
    )
    ap.add_argument("--seeds", type=int, default=3, help="training seeds per task")
    ap.add_argument("--draws", type=int, default=2000, help="resampled draws per size")
    ap.add_argument("--out", type=Path, default=Path("results/validation_size"))
    args = ap.parse_args(argv)
    tasks = args.task or list(STUDIES)
    parts, curve_parts, inputs = [], [], {}
    for task in tasks:
        pool = args.pool or {"carracing": 8, "rehab": 128}[task]
        print(f"{task}: {args.seeds} training seeds, {pool} validation episodes", flush=True)
        rows, curves, inputs[task] = measure(task, pool, args.seeds, args.draws)
        parts.append(rows)
        curve_parts.append(curves)
    table = pd.concat(parts, ignore_index=True)
    curves = pd.concat(curve_parts, ignore_index=True)
    chosen = choose(table)
    table["chosen"] = table["n_episodes"] == table["task"].map(chosen)
    meta = run_metadata(
        inputs=inputs,
        settings={"spread_bar": SPREAD_BAR, "cost_bar": COST_BAR, "sizes": list(SIZES),
                  "seeds": args.seeds,
                  "draws": args.draws, "resample_seed": 0},
    )  # fmt: skip
    source = made_by(meta)
    args.out.mkdir(parents=True, exist_ok=True)
    write_table_atomic(args.out / "validation_size.parquet", table, meta)
    write_table_atomic(args.out / "validation_curves.parquet", curves, meta)
    figure(table, curves, chosen, args.out / "validation_size.png")
    from safe_bc.data.atomic import write_text_atomic

    text = markdown(table, chosen, source)
    write_text_atomic(args.out / "validation_size.md", text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
