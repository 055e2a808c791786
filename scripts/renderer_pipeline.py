"""Does a pipeline that runs on the approximate renderer do as well as the exact one?

Usage::

    .venv/bin/python -m scripts.renderer_pipeline     # after scripts.renderer_cost

``scripts.renderer_cost`` showed that agents trained on exact frames drive worse on raster
frames. This asks the question that decides whether the raster renderer could replace the
exact one, with every CarRacing result rerun on it: an agent whose demonstrations, limit d_s,
training and evaluation all use raster frames, against the committed exact pipeline.

1. ``safe-bc collect --renderer raster`` with the default demonstrations' settings (5
   episodes, seed 0, the same expert and drift perturbation; the drift's release reads the
   frame's safety distance, so the trajectories may differ slightly) into ``--data``;
2. ``safe-bc train --selection.alpha A --seed K`` for each training seed, the settings of the
   committed CarRacing improvement starts (``results/improve/carracing/starts``);
3. evaluation on the raster env on the tracks of ``renderer_cost`` (its ``--eval-seed`` and
   ``--episodes``), against the raster demonstrations' own d_s;
4. paired with the exact pipeline's rows of ``results/ablation/renderer/episodes.parquet``
   (the committed starts, exact demonstrations and frames, same training seeds and tracks),
   crossed bootstrap over training seeds and tracks.

``--exact results/table1_episodes.parquet --method "alpha=0.1 (rest=all)" --seeds 0 1 2 3 4 5
6 7 --name pipeline_table1`` pairs with a Table 1 row instead (its 8 training seeds x 20
tracks, its eval seed, its method's alpha).

Writes ``<name>_episodes.parquet``, ``<name>_paired.parquet`` and ``<name>.md`` under
``--out`` (``--name`` default ``pipeline``). Demonstrations and agents go to ``--data`` (not
committed; reused by a rerun at the same revision).
"""

from __future__ import annotations

import argparse
import shlex
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import pandas as pd

from safe_bc import api
from safe_bc.atomic import write_text_atomic
from safe_bc.data.store import load_demonstrations, read_table, write_table_atomic
from safe_bc.provenance import git_revision, run_metadata


def main(argv: list[str] | None = None) -> int:
    from safe_bc.bc.checkpoint import load_checkpoint
    from safe_bc.distributed.evaluate import evaluate_policies
    from safe_bc.envs import EnvConfig
    from safe_bc.evaluation import EvalConfig, NetSource
    from safe_bc.jobs import CollectJob, TrainJob
    from safe_bc.metrics import paired_crossed
    from safe_bc.run_config import RunConfig
    from safe_bc.selection import SelectionConfig

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--alpha", type=float, default=0.1, help="the starts' safety focus")
    p.add_argument("--exact", type=Path, default=Path("results/ablation/renderer/episodes.parquet"))
    p.add_argument("--data", type=Path, default=None,
                   help="demonstrations and agents (default: data/renderer_pipeline/<revision>, "
                   "so a renderer change is never reused)")  # fmt: skip
    p.add_argument(
        "--method",
        default=None,
        help="pair with this method's rows of --exact (a Table 1 episodes table)",
    )
    p.add_argument("--name", default="pipeline", help="output file prefix")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--out", type=Path, default=Path("results/ablation/renderer"))
    args = p.parse_args(argv)
    command = shlex.join(["python", "-m", "scripts.renderer_pipeline",
                          *(sys.argv[1:] if argv is None else argv)])  # fmt: skip

    if args.data is None:
        args.data = Path("data/renderer_pipeline") / git_revision()[:12]
    exact_all, exact_meta = read_table(args.exact)
    if args.method is None:  # scripts.renderer_cost's table
        exact = exact_all[exact_all["renderer"] == "exact"]
        demos_path, n_tracks = exact_meta["demos"], int(exact_meta["episodes"])
    else:  # a Table 1 episodes table
        exact = exact_all[exact_all["method"] == args.method]
        t1 = exact_meta["config"]
        if args.method not in t1["methods"]:
            raise SystemExit(f"{args.exact}: no method {args.method!r}")
        args.alpha = float(t1["methods"][args.method]["alpha"])
        demos_path, n_tracks = t1["demos"], int(t1["episodes"])
    if exact.empty:
        raise SystemExit(f"{args.exact}: no exact rows (run scripts.renderer_cost first)")
    missing = sorted(set(args.seeds) - set(exact["train_seed"]))
    if missing:
        raise SystemExit(f"{args.exact}: no exact rows for training seeds {missing}")
    exact_demos = load_demonstrations(Path(demos_path))

    demos_dir = args.data / "demos"
    if not (demos_dir / "dataset.json").exists():
        demos_dir.parent.mkdir(parents=True, exist_ok=True)
        api.collect(
            CollectJob(renderer="raster", out=demos_dir, seed=0, workers=args.workers, quiet=True)
        )
    demos = load_demonstrations(demos_dir)
    sources: dict[str, Any] = {}
    for k in args.seeds:
        agent = args.data / "agents" / f"seed{k}"
        if not (agent / "weights.pt").exists():
            run = RunConfig(SelectionConfig(alpha=args.alpha))
            run = replace(run, bc=replace(run.bc, train=replace(run.bc.train, seed=k)))
            api.train(TrainJob(agent, demos_dir, run, quiet=True), task_eps=True)
        model, cfg = load_checkpoint(agent)
        sources[f"seed{k}"] = NetSource.from_model(model, cfg)

    config = EvalConfig(
        episodes=n_tracks,
        workers=args.workers,
        seed=int(exact_meta["eval_seed"]),
        env=EnvConfig(renderer="raster"),
    )
    episodes, _ = evaluate_policies(sources, config, thresholds=demos.limits)
    episodes["train_seed"] = episodes["policy"].str.removeprefix("seed").astype(int)
    both = pd.concat(
        [
            exact.assign(method="exact pipeline", renderer="exact"),
            episodes.assign(method="raster pipeline", renderer="raster"),
        ],
        ignore_index=True,
    )
    both = both[both["train_seed"].isin(args.seeds)]
    paired = paired_crossed(both, "exact pipeline", ["reward", "violation_steps"])

    limits = {
        "exact pipeline": [float(x) for x in exact_demos.limits],
        "raster pipeline": [float(x) for x in demos.limits],
    }
    meta = run_metadata(seeds=args.seeds, alpha=args.alpha, demos=str(demos_dir),
                        exact_method=args.method,
                        exact=str(args.exact), exact_revision=exact_meta.get("git_revision"),
                        episodes=config.episodes, eval_seed=config.seed, limits=limits,
                        demo_pairs={"exact pipeline": len(exact_demos.actions),
                                    "raster pipeline": len(demos.actions)})  # fmt: skip
    meta["command"] = command
    write_table_atomic(args.out / f"{args.name}_episodes.parquet", both, meta)
    write_table_atomic(args.out / f"{args.name}_paired.parquet", paired, meta)
    write_text_atomic(args.out / f"{args.name}.md", markdown(both, paired, meta))
    print((args.out / f"{args.name}.md").read_text())
    return 0


def markdown(both: pd.DataFrame, paired: pd.DataFrame, meta: dict[str, Any]) -> str:
    """The report."""
    beyond = both.assign(b=both.violation_steps > 0).groupby("method")["b"].sum()
    table = both.groupby("method")[["reward", "violation_steps"]].mean()
    table["episodes_beyond"] = beyond
    table["d_s (left, front, right)"] = [
        ", ".join(f"{x:.2f}" for x in meta["limits"][m]) for m in table.index
    ]
    table["demo pairs"] = [meta["demo_pairs"][m] for m in table.index]
    n_seeds, n_tracks = both.train_seed.nunique(), both.env_seed.nunique()
    return "\n".join(
        [
            "# Exact pipeline vs raster pipeline (demonstrations, d_s, training, evaluation)",
            "",
            f"Command: `{meta['command']}` at `{meta['git_revision']}`; exact rows from "
            f"`{meta['exact']}` (made at `{meta['exact_revision']}`). {n_seeds} training seeds "
            f"x {n_tracks} tracks (eval seed {meta['eval_seed']}), safe-bc train "
            f"--selection.alpha {meta['alpha']}; each pipeline's violations count against its own "
            "d_s.",
            "",
            table.reset_index().to_markdown(index=False, floatfmt=".4g"),
            "",
            "Paired raster pipeline - exact pipeline on the same (training seed, track) cells, "
            "95% crossed bootstrap:",
            "",
            paired.to_markdown(index=False, floatfmt=".3g"),
            "",
        ]
    )


if __name__ == "__main__":
    raise SystemExit(main())
