"""The ``safe-bc`` command line."""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NoReturn, get_args

from safe_bc.bc.checkpoint import CheckpointError
from safe_bc.bc.config import PreprocessConfig
from safe_bc.data.store import DatasetError
from safe_bc.distributed.runtime import RayUnavailableError, check_ray_address
from safe_bc.docs import field_doc
from safe_bc.envs.factory import Renderer
from safe_bc.locks import OutputLockedError, check_output_folder, output_lock, output_locks
from safe_bc.selection import RULES, Baseline
from safe_bc.tasks import DEFAULT_TASK, TASKS

DEFAULT_DEMOS = Path("data/demos")


def _number(name: str, cast: type, ok: Callable[[Any], bool], rule: str) -> Callable[[str], Any]:
    """An argparse type: ``cast`` the text, then check it, with a message naming the flag."""
    kind = "an integer" if cast is int else "a number"

    def parse(text: str) -> Any:
        try:
            value = cast(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be {kind}, got {text!r}") from None
        if not ok(value):
            raise argparse.ArgumentTypeError(f"{name} must be {rule}, got {value}")
        return value

    return parse


def _positive(name: str) -> Callable[[str], int]:
    return _number(name, int, lambda v: v >= 1, ">= 1")


def _non_negative_int(name: str) -> Callable[[str], int]:
    return _number(name, int, lambda v: v >= 0, ">= 0")


def _positive_float(name: str) -> Callable[[str], float]:
    return _number(name, float, lambda v: math.isfinite(v) and v > 0, "finite, > 0")


def _non_negative_float(name: str) -> Callable[[str], float]:
    return _number(name, float, lambda v: math.isfinite(v) and v >= 0, "finite, >= 0")


def _unit_interval(name: str) -> Callable[[str], float]:
    return _number(name, float, lambda v: 0 <= v <= 1, "in [0, 1]")


def _finite_float(name: str) -> Callable[[str], float]:
    return _number(name, float, math.isfinite, "finite")


RAY_COMMANDS = frozenset({"collect", "evaluate", "expert", "reproduce", "tune"})
"""Commands that may start or join Ray: with ``RAY_ADDRESS`` set they join the cluster before
they write anything."""

SELECTION_FLAGS: dict[str, dict[str, Any]] = {
    "eps": {"type": _non_negative_float("--eps"), "help": "critical-zone width"},
    "alpha": {"type": _unit_interval("--alpha"), "help": "share of T_eps in every batch"},
    "rest": {"help": "where the rest of a batch comes from"},
    "threshold": {"help": "d_s: the demonstrations' largest cost, or a quantile of it"},
    "quantile": {
        "type": _number("--quantile", float, lambda v: 0 < v <= 1, "in (0, 1]"),
        "help": "the quantile of --threshold quantile",
        "requires": ("threshold", "quantile"),
    },
    "combine": {"help": "a pair is critical in any dimension or in all of them"},
    "mode": {"help": "training rule: the alpha mix, BC-Safe or cost-weighted BC"},
    "segment_steps": {
        "type": _positive("--segment-steps"),
        "help": "BC-Safe's segment length in scored steps",
    },
    "beta": {
        "type": _number("--beta", float, lambda v: math.isfinite(v) and v >= 0, "finite, >= 0"),
        "help": "cost-weighted BC's strength",
    },
}
"""``SelectionConfig`` fields on ``safe-bc train``: field -> ``add_argument`` keywords, plus
``requires=(field, value)`` for a flag that only applies with another's value. A field typed
with a ``Literal`` gets its choices from the type; every flag defaults to the config's default.
A new field is one entry here (tests/test_cli.py fails while a field has none)."""
for _mode, _rule in RULES.items():  # a rule's own fields apply with that mode only
    for _field in _rule.params:
        SELECTION_FLAGS[_field]["requires"] = ("mode", _mode)


def _selection_args(p: argparse.ArgumentParser, **defaults: str) -> None:
    """One ``--flag`` per entry of :data:`SELECTION_FLAGS`; ``defaults`` describe defaults
    that are not the config's (e.g. ``eps="the task's"``)."""
    import dataclasses
    import typing

    from safe_bc.selection import SelectionConfig

    hints = typing.get_type_hints(SelectionConfig)
    own = {f.name: f.default for f in dataclasses.fields(SelectionConfig)}
    for name, settings in SELECTION_FLAGS.items():
        kw = {k: v for k, v in settings.items() if k != "requires"}
        if "type" not in kw:
            kw["choices"] = typing.get_args(hints[name])
        kw["help"] = f"{kw.get('help', name)} (default: {defaults.get(name, own[name])})"
        p.add_argument(f"--{name.replace('_', '-')}", default=None, **kw)


def _selection_config(args: argparse.Namespace, **defaults: Any) -> Any:
    """The ``SelectionConfig`` of the flags given, else ``defaults``, else the config's own.

    Raises:
        ValueError: a flag given without the setting it applies to.
    """
    from safe_bc.selection import SelectionConfig

    given = {n: getattr(args, n) for n in SELECTION_FLAGS if getattr(args, n, None) is not None}
    values = {**defaults, **given}
    for name in given:
        other, needed = SELECTION_FLAGS[name].get("requires", (None, None))
        if other is not None and values.get(other) != needed:
            raise ValueError(
                f"--{name.replace('_', '-')} applies with --{other.replace('_', '-')} {needed}"
            )
    return SelectionConfig(**values)


def _env_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--env",
        choices=TASKS,
        default=DEFAULT_TASK,
        help="task: CarRacing-v3 (default) or the rehabilitation pathway",
    )
    p.add_argument(
        "--renderer",
        choices=list(get_args(Renderer)),
        default="fast",
        help="CarRacing renderer (fast is pixel-identical to stock; raster is faster but "
        "approximate, see results/ablation/renderer/)",
    )


def _cmd_collect(args: argparse.Namespace) -> int:
    from safe_bc.distributed.collect import collect
    from safe_bc.tasks import task_defaults

    defaults = task_defaults(args.env, renderer=args.renderer)
    args.out = args.out or Path(defaults.demos)
    given = {"episodes": args.episodes, "encoding": args.encoding}
    config = defaults.collect_config(
        workers=args.workers,
        seed=args.seed,
        max_steps=args.max_steps,
        **{k: v for k, v in given.items() if v is not None},
    )
    report = collect(config, args.out, progress=not args.quiet)
    print(
        f"{args.out}: {len(report.collected)} episode(s) collected, {len(report.reused)} reused, "
        f"{report.steps} steps in {report.seconds:.1f} s ({report.steps_per_s:.0f} steps/s), "
        f"{report.worker_restarts} worker restart(s)"
    )
    return 0


def _cmd_describe(args: argparse.Namespace) -> int:
    import json

    from safe_bc.atomic import write_json_atomic
    from safe_bc.data.store import load_demonstrations, read_episodes, read_meta
    from safe_bc.experiment import select_for
    from safe_bc.metrics import combined
    from safe_bc.plots import plot_cost_histograms
    from safe_bc.provenance import provenance
    from safe_bc.selection import SelectionConfig
    from safe_bc.tasks import task_defaults, task_of

    check_output_folder(args.out)
    demos = load_demonstrations(args.demos)
    meta = read_meta(args.demos)
    if args.eps is None:
        args.eps = task_defaults(task_of(meta.env_id)).eps
    sel = select_for(demos, SelectionConfig(eps=args.eps, alpha=0.0))
    scored = demos.scored
    offroad = sum(int(ep.offroad.sum()) for ep in read_episodes(args.demos))
    # the largest cost a state can have: cost + distance is the measurable range per dim
    top = (demos.costs + demos.safety).max(axis=0)
    limits = {
        d: {
            "d_s": float(sel.thresholds[j]),
            "closest_distance": float(demos.safety[scored, j].min()),
            "max_cost": float(top[j]),
            "inside_range": bool(sel.thresholds[j] < top[j]),
            "critical_pairs": int(sel.per_dim[:, j].sum()),
        }
        for j, d in enumerate(demos.safety_dims)
    }
    summary = {
        "demos": str(args.demos),
        "pairs": len(demos),
        "scored_pairs": int(scored.sum()),
        "episodes": len(set(demos.episode_ids.tolist())),
        "safety_mean": float(combined(demos.safety[scored]).mean()),
        "per_dim": {
            d: {
                "mean": float(demos.safety[scored, j].mean()),
                "min": float(demos.safety[scored, j].min()),
            }
            for j, d in enumerate(demos.safety_dims)
        },
        "offroad_frames": offroad,
        "limits": limits,
        "eps": args.eps,
        "critical_pairs": int(sel.n_critical),
        "critical_share": float(sel.n_critical / sel.n_valid),
        "selection": sel.to_dict(),
        "dataset": json.loads(meta.to_json()),
        "described_by": {"command": " ".join(sys.argv), "provenance": provenance()},
    }
    args.out.mkdir(parents=True, exist_ok=True)
    title = f"{args.demos}: {len(demos)} pairs, rev {meta.provenance.get('git_revision', '?')[:12]}"
    plot_cost_histograms(demos, args.out / "cost_histograms.png", eps=args.eps, title=title)
    write_json_atomic(args.out / "summary.json", summary)
    keys = ("pairs", "episodes", "safety_mean", "offroad_frames", "critical_share")
    print(json.dumps({k: summary[k] for k in keys}))
    for d, v in limits.items():
        print(
            f"{d:>6}: d_s {v['d_s']:.2f} of {v['max_cost']:.2f} (closest distance "
            f"{v['closest_distance']:.2f}), critical pairs at eps {args.eps:g}: "
            f"{v['critical_pairs']}"
        )
    print(f"wrote {args.out / 'cost_histograms.png'} and {args.out / 'summary.json'}")
    return 0


def _cmd_train(args: argparse.Namespace) -> int:
    with output_lock(args.out):
        return _train(args)


def _train(args: argparse.Namespace) -> int:
    import json

    from safe_bc.bc import BCConfig, NetworkConfig, PreprocessConfig, TrainConfig
    from safe_bc.bc.checkpoint import checkpoint_unit
    from safe_bc.data.store import load_demonstrations, read_meta
    from safe_bc.experiment import RunConfig, save_selection, train_run
    from safe_bc.provenance import run_metadata
    from safe_bc.tasks import dataset_action_bounds, task_defaults, task_of

    demos = load_demonstrations(args.demos)
    env_id = read_meta(args.demos).env_id
    task = task_defaults(task_of(env_id))
    run = RunConfig(
        _selection_config(args, eps=task.eps),
        BCConfig(
            preprocess=PreprocessConfig(
                frame_stack=args.frame_stack,
                crop_bar=args.crop_bar,
                grayscale=args.grayscale,
                mask_steering=args.mask_steering,
            ),
            network=NetworkConfig(
                hidden=args.hidden,
                **({} if args.channels is None else {"channels": tuple(args.channels)}),
            ),
            train=TrainConfig(
                batches=args.batches, batch_size=args.batch_size, lr=args.lr, seed=args.seed
            ),
        ),
    )
    bounds = dataset_action_bounds(args.demos)
    result, selection = train_run(demos, run, progress=not args.quiet, action_bounds=bounds)
    meta = run_metadata(
        demos=str(args.demos), env_id=env_id, run=run.to_dict(), train=result.summary()
    )
    with checkpoint_unit(args.out) as unit:  # weights, config and selection: old or new, whole
        result.save(unit, extra=json.loads(json.dumps(meta, default=str)))
        save_selection(unit, demos, selection, meta)
    print(
        f"{args.out}: trained {run.bc.train.batches} batches, final loss "
        f"{result.final_loss:.4f}, {result.samples_per_s:.0f} samples/s; "
        f"|T_eps| = {selection.n_critical} of {selection.n_valid} scored pairs"
    )
    return 0


def _cmd_evaluate(args: argparse.Namespace) -> int:
    import numpy as np

    from safe_bc.bc import load_checkpoint, read_checkpoint_meta
    from safe_bc.data.store import read_table, write_table_atomic
    from safe_bc.distributed.evaluate import evaluate
    from safe_bc.evaluation import EvalConfig, NetSource
    from safe_bc.metrics import METRICS
    from safe_bc.provenance import run_metadata
    from safe_bc.tasks import check_net_fits_task, task_defaults, task_of

    check_output_folder(args.out)
    model, bc_cfg = load_checkpoint(args.checkpoint)
    extra = read_checkpoint_meta(args.checkpoint).get("extra", {})
    _, sel_meta = read_table(args.checkpoint / "selection.parquet")
    if "env_id" not in extra:
        raise ValueError(
            f"{args.checkpoint}: no env_id in the checkpoint; train with safe-bc train"
        )
    spec = model.spec
    check_net_fits_task(spec.obs_shape, spec.action_dim, extra["env_id"], args.checkpoint)
    task = task_defaults(task_of(extra["env_id"]))
    sel_cfg = sel_meta.get("config", {})
    cfg = EvalConfig(
        episodes=args.episodes,
        workers=args.workers,
        seed=args.eval_seed,
        env=task.env,
        max_steps=args.max_steps,
        eps=float(sel_cfg.get("eps", task.eps)),
        combine=sel_cfg.get("combine", "any"),
    )
    result = evaluate(
        {"agent": NetSource.from_model(model, bc_cfg)},
        cfg,
        np.asarray(sel_meta["thresholds"]),
        progress=not args.quiet,
    )
    episodes, steps, table = result.episodes, result.steps, result.summary
    metrics = [m for m in METRICS if m in table]
    meta = run_metadata(
        checkpoint=str(args.checkpoint),
        trained_with=extra.get("run"),
        eval_seed=args.eval_seed,
        env_seeds=episodes["env_seed"].tolist(),
    )
    args.out.mkdir(parents=True, exist_ok=True)
    write_table_atomic(args.out / "episodes.parquet", episodes, meta)
    write_table_atomic(args.out / "steps.parquet", steps, meta)
    write_table_atomic(args.out / "summary.parquet", table, meta)
    r = table.iloc[0]
    for m in metrics:
        print(f"{m:>15}: {r[m]:9.3f}  95% CI [{r[m + '_lo']:.3f}, {r[m + '_hi']:.3f}]")
    print(f"wrote {args.out}/episodes.parquet, steps.parquet, summary.parquet")
    return 0


def _cmd_expert(args: argparse.Namespace) -> int:
    from safe_bc.atomic import write_text_atomic
    from safe_bc.data.store import load_demonstrations, write_table_atomic
    from safe_bc.distributed.collect import ensure_demos
    from safe_bc.distributed.evaluate import evaluate
    from safe_bc.evaluation import EvalConfig, ExpertSource
    from safe_bc.metrics import METRICS
    from safe_bc.provenance import run_metadata
    from safe_bc.report import markdown_table
    from safe_bc.tasks import task_defaults

    check_output_folder(args.out)
    task = task_defaults(args.env)
    demos_path = args.demos or Path(task.demos)
    ensure_demos(demos_path, task.collect_config(), progress=not args.quiet)
    demos = load_demonstrations(demos_path)
    limits = demos.limits
    cfg = EvalConfig(
        episodes=args.episodes,
        workers=args.workers,
        seed=args.eval_seed,
        env=task.env,
        eps=task.eps,
    )
    result = evaluate({"expert": ExpertSource(task.expert)}, cfg, limits, progress=not args.quiet)
    episodes, table = result.episodes, result.summary
    metrics = [m for m in METRICS if m in table]
    metrics += [c for c in table.columns if c.startswith("safety_") and c.endswith("_mean")]
    metrics = list(dict.fromkeys(metrics))
    meta = run_metadata(
        expert=repr(task.expert),
        env=args.env,
        episodes=args.episodes,
        eval_seed=args.eval_seed,
        env_seeds=episodes["env_seed"].tolist(),
        demos=str(demos_path),
        limits=[float(x) for x in limits],
        eps=task.eps,
    )
    args.out.mkdir(parents=True, exist_ok=True)
    write_table_atomic(args.out / "expert_episodes.parquet", episodes, meta)
    write_table_atomic(args.out / "expert.parquet", table, meta)
    r = table.iloc[0]
    dims = ", ".join(f"{d} {x:.2f}" for d, x in zip(demos.safety_dims, limits, strict=True))
    cells = [[m, f"{r[m]:.2f}", f"[{r[m + '_lo']:.2f}, {r[m + '_hi']:.2f}]"] for m in metrics]
    lines = [markdown_table(cells, ["metric", "mean", "95% CI"])]
    lines += [
        "",
        f"{len(episodes)} held-out episodes (seeds {episodes['env_seed'].min()}..."
        f"{episodes['env_seed'].max()}); limits d_s (worst cost of the demonstrations in "
        f"{demos_path}): {dims}; episodes with a violation: "
        f"{int(r['episodes_with_violation'])}/{len(episodes)}, with an off-road step: "
        f"{int((episodes['offroad_steps'] > 0).sum())}/{len(episodes)}; "
        f"min reward {episodes['reward'].min():.1f}; code {meta['git_revision']}, "
        f"command `{meta['command']}`",
        "",
    ]
    write_text_atomic(args.out / "expert.md", "\n".join(lines))
    print("\n".join(lines))
    return 0


def _reproduce_config(args: argparse.Namespace) -> Any:
    """The ``ReproduceConfig`` of ``safe-bc reproduce``'s arguments."""
    from safe_bc.bc import BCConfig, TrainConfig
    from safe_bc.reproduce import ReproduceConfig
    from safe_bc.tasks import task_defaults

    task = task_defaults(args.env)
    args.demos = args.demos or Path(task.demos)
    args.out = args.out or Path(task.results)
    return ReproduceConfig(
        demos=args.demos,
        out=args.out,
        alphas=tuple(args.alphas),
        readings=tuple(args.readings),
        baselines=tuple(args.baselines),
        segment_steps=args.segment_steps,
        beta=args.beta,
        train_seeds=tuple(range(args.train_seeds)),
        episodes=args.episodes,
        workers=args.workers,
        bc=BCConfig(train=TrainConfig(batches=args.batches)),
        max_steps=args.max_steps,
        eval_seed=args.eval_seed,
        eps=task.eps if args.eps is None else args.eps,
        task=args.env,
    )


def _cmd_reproduce(args: argparse.Namespace) -> int:
    from safe_bc.reproduce import run_reproduce

    config = _reproduce_config(args)
    check_output_folder(config.out)
    if args.render_only:
        from safe_bc.reproduce import rerender

        table = rerender(config)
    else:
        table = run_reproduce(config, progress=not args.quiet)
    cols = ["method", "reward", "safety_mean", "safety_std", "offroad_steps"]
    print(table[cols].to_string(index=False, float_format=lambda x: f"{x:.2f}"))
    print(f"wrote {args.out / 'table1.parquet'} and {args.out / 'table1.md'}")
    return 0


def _cmd_tune(args: argparse.Namespace) -> int:
    import dataclasses
    import shlex

    from safe_bc.study import load_study

    fields = {
        "trials": "trials",
        "storage": "storage",
        "threshold": "threshold",
        "concurrent": "max_concurrent",
        "rollout_workers": "rollout_workers",
        "cpus_per_trial": "cpus_per_trial",
        "demos": "demos",
        "results": "results",
    }
    given = {flag: getattr(args, flag) for flag in fields if getattr(args, flag) is not None}
    spec = dataclasses.replace(
        load_study(args.study), **{fields[flag]: value for flag, value in given.items()}
    )
    command = ["safe-bc", "tune", str(args.study)]
    for flag, value in given.items():
        command += [f"--{flag.replace('_', '-')}", str(value)]
    command += ["--fresh"] if args.fresh else []

    from safe_bc.distributed.study import experiment_location, format_outcome, run_study

    # one study run per results folder and per (local) Tune experiment folder
    storage, experiment = experiment_location(spec)
    outputs = [(spec.results / spec.name, "--results")]
    if "://" not in storage:
        outputs.append((Path(experiment), "--storage"))
    with output_locks(outputs):
        outcome = run_study(spec, fresh=args.fresh, command=shlex.join(command))
    print(format_outcome(outcome, spec.params))
    if not outcome.complete:
        return 130
    return 1 if outcome.errors or outcome.winner is None else 0


def _cmd_improve(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from safe_bc.improve import ImproveConfig, LocalEnvs, improve

    names = ("eps", "cost_signal", "cost_margin", "cost_budget", "lambda_lr", "anchor",
             "anchor_coef", "iterations", "episodes_per_iter")  # fmt: skip
    given = {k: getattr(args, k) for k in names if getattr(args, k) is not None}
    config = ImproveConfig(shield=args.shield, lagrangian=args.lagrangian, seed=args.seed, **given)
    bar = tqdm(total=config.iterations, desc=f"improve ({config.mode})", disable=args.quiet)

    def show(row: dict[str, float]) -> None:
        bar.n = int(row["iteration"])
        bar.set_postfix(reward=f"{row['train_reward']:.2f}", lam=f"{row['lambda']:.2f}",
                        viol=f"{row['train_violation_steps']:.2f}")  # fmt: skip
        bar.refresh()

    envs = LocalEnvs
    if args.rollout_workers:
        from safe_bc.distributed.envs import ray_envs

        envs = ray_envs(args.rollout_workers)
    with output_lock(args.out), bar:
        result = improve(args.start, args.out, config, demos=args.demos, on_iteration=show,
                         envs=envs)  # fmt: skip
    last = result.history.dropna(subset=["val_reward"]).iloc[-1]
    print(
        f"{args.out}: {config.mode}, {result.iterations} iterations "
        f"({'resumed at ' + str(result.resumed_at) if result.resumed_at else 'fresh'}), "
        f"{int(last['env_steps'])} env steps; validation reward {last['val_reward']:.2f}, "
        f"violating sessions / patient {last['val_violation_steps']:.3f}, lambda "
        f"{last['lambda']:.2f}; policy of iteration {result.kept_iteration} in "
        f"{args.out / 'policy'}"
    )
    return 0


def _cmd_export(args: argparse.Namespace) -> int:
    from safe_bc.data.minari_export import MinariNotInstalledError, export_minari

    try:
        dataset = export_minari(args.demos, args.dataset_id, author=args.author)
    except MinariNotInstalledError as e:
        raise ValueError(str(e)) from None
    print(
        f"{args.demos} -> Minari dataset {args.dataset_id}: {dataset.total_episodes} episode(s), "
        f"{dataset.total_steps} steps in {dataset.storage.data_path.parent}; load it with "
        f"minari.load_dataset({args.dataset_id!r})"
    )
    return 0


def _cmd_render(args: argparse.Namespace) -> int:
    from safe_bc.render import render_command

    print(
        render_command(
            args.out,
            args.seed,
            checkpoint=args.checkpoint,
            expert=args.expert,
            paths=args.paths,
            demos=args.demos,
            eps=args.eps,
            max_steps=args.max_steps,
            scale=args.scale,
            fps=args.fps,
        )
    )
    return 0


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (``safe-bc train: error: ...``, exit code 2) instead of
    the usage block before them; ``-h`` still shows the usage."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} -h)\n")


TRAIN, NETWORK = ("safe_bc.bc.config", "TrainConfig"), ("safe_bc.bc.config", "NetworkConfig")
IMPROVE = ("safe_bc.improve.config", "ImproveConfig")
DEMOS = "demonstration dataset directory"
WORKERS = "Ray actors that run the episodes"
EVAL_SEED = "block of held-out seeds (tracks or patients) the episodes are drawn from"
MAX_STEPS = "step cap per episode (default: the env's, 1000 for CarRacing)"
ENV = "the testbed: carracing or rehab"


def _doc(where: tuple[str, str], field: str) -> str:
    """Help text of an option that sets a config field: the field's docstring."""
    return field_doc(*where, field)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``safe-bc``."""
    parser = _Parser(prog="safe-bc", description="Safety-focused behaviour cloning as a Ray study.")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("collect", help="collect expert demonstrations into Parquet")
    p.add_argument(
        "--episodes", type=_positive("--episodes"), default=None, help="default: 5 (rehab: 150)"
    )
    p.add_argument("--workers", type=_positive("--workers"), default=2, help=WORKERS)
    p.add_argument(
        "--seed",
        type=_non_negative_int("--seed"),
        default=0,
        help="seed of the episodes' tracks (patients) and the expert's noise",
    )
    p.add_argument(
        "--out", type=Path, default=None, help="default: data/demos (rehab: data/rehab_demos)"
    )
    p.add_argument("--max-steps", type=_positive("--max-steps"), default=None, help=MAX_STEPS)
    p.add_argument(
        "--encoding",
        choices=["png", "raw", "vector"],
        default=None,
        help="how observations are stored (default: png for frames, vector for rehab)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    _env_args(p)
    p.set_defaults(func=_cmd_collect)

    p = sub.add_parser("describe", help="cost histograms and summary of a demonstration set")
    p.add_argument("--demos", type=Path, default=DEFAULT_DEMOS, help=DEMOS)
    p.add_argument("--out", type=Path, default=Path("results/demos"), help="where the summary goes")
    p.add_argument(
        "--eps",
        type=_non_negative_float("--eps"),
        default=None,
        help="critical-zone width (default: the task's, 2 px / 0.05)",
    )
    p.set_defaults(func=_cmd_describe)

    p = sub.add_parser("train", help="select T_eps and train one BC agent (checkpoint)")
    p.add_argument("--demos", type=Path, default=DEFAULT_DEMOS, help=DEMOS)
    p.add_argument("--out", type=Path, required=True, help="checkpoint directory")
    _selection_args(p, eps="the task's, 2 px / 0.05")
    p.add_argument("--batches", type=_positive("--batches"), default=2000,
                   help=_doc(TRAIN, "batches"))  # fmt: skip
    p.add_argument("--batch-size", type=_positive("--batch-size"), default=64,
                   help=_doc(TRAIN, "batch_size"))  # fmt: skip
    p.add_argument("--lr", type=_positive_float("--lr"), default=3e-4, help=_doc(TRAIN, "lr"))
    p.add_argument("--hidden", type=_positive("--hidden"), default=128,
                   help=_doc(NETWORK, "hidden"))  # fmt: skip
    pre = PreprocessConfig()
    p.add_argument(
        "--frame-stack",
        type=_positive("--frame-stack"),
        default=pre.frame_stack,
        help="consecutive frames stacked along channels (PreprocessConfig.frame_stack)",
    )
    for field, what in (
        ("crop_bar", "drop CarRacing's indicator bar, rows 84-95"),
        ("grayscale", "one luma channel instead of RGB"),
        ("mask_steering", "black out the bar's steering-angle indicator"),
    ):
        p.add_argument(
            "--" + field.replace("_", "-"),
            action=argparse.BooleanOptionalAction,
            default=getattr(pre, field),
            help=f"{what} (PreprocessConfig.{field})",
        )
    p.add_argument(
        "--channels",
        type=_positive("--channels"),
        nargs="*",
        default=None,
        help="conv channels of the CNN, e.g. 16 32 32 (default: NetworkConfig.channels)",
    )
    p.add_argument("--seed", type=_non_negative_int("--seed"), default=0,
                   help=_doc(TRAIN, "seed"))  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_train)

    p = sub.add_parser("evaluate", help="evaluate a checkpoint on held-out tracks (or patients)")
    p.add_argument("--checkpoint", type=Path, required=True, help="a safe-bc train checkpoint")
    p.add_argument("--episodes", type=_positive("--episodes"), default=10,
                   help="held-out episodes (tracks or patients), one each")  # fmt: skip
    p.add_argument("--workers", type=_positive("--workers"), default=2, help=WORKERS)
    p.add_argument("--eval-seed", type=_non_negative_int("--eval-seed"), default=0,
                   help=EVAL_SEED)  # fmt: skip
    p.add_argument("--max-steps", type=_positive("--max-steps"), default=None, help=MAX_STEPS)
    p.add_argument("--out", type=Path, required=True, help="where the episode table goes")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_evaluate)

    p = sub.add_parser("expert", help="measure the expert on held-out tracks (or patients)")
    p.add_argument("--env", choices=TASKS, default=DEFAULT_TASK, help=ENV)
    p.add_argument("--episodes", type=_positive("--episodes"), default=20,
                   help="held-out episodes (tracks or patients), one each")  # fmt: skip
    p.add_argument("--workers", type=_positive("--workers"), default=2, help=WORKERS)
    p.add_argument("--eval-seed", type=_non_negative_int("--eval-seed"), default=3,
                   help=EVAL_SEED)  # fmt: skip
    p.add_argument("--out", type=Path, default=Path("results/expert"),
                   help="where the tables go")  # fmt: skip
    p.add_argument(
        "--demos",
        type=Path,
        default=None,
        help="demonstrations whose worst costs d_s define violations (default: the task's; "
        "built if absent)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_expert)

    p = sub.add_parser("reproduce", help="rerun the paper's Table 1 with CIs")
    p.add_argument("--env", choices=TASKS, default=DEFAULT_TASK, help=ENV)
    p.add_argument("--demos", type=Path, default=None, help="default: the task's demo set")
    p.add_argument(
        "--out", type=Path, default=None, help="default: results/ (rehab: results/rehab)"
    )
    p.add_argument(
        "--train-seeds",
        type=_positive("--train-seeds"),
        default=8,
        help="training seeds 0..N-1, shared by every method (default: 8)",
    )
    p.add_argument(
        "--episodes",
        type=_positive("--episodes"),
        default=20,
        help="held-out tracks, the same for every agent (default: 20)",
    )
    p.add_argument("--workers", type=_positive("--workers"), default=2, help=WORKERS)
    p.add_argument("--batches", type=_positive("--batches"), default=2000,
                   help=_doc(TRAIN, "batches"))  # fmt: skip
    p.add_argument("--max-steps", type=_positive("--max-steps"), default=None, help=MAX_STEPS)
    p.add_argument("--eval-seed", type=_non_negative_int("--eval-seed"), default=0,
                   help=EVAL_SEED)  # fmt: skip
    p.add_argument(
        "--eps", type=_non_negative_float("--eps"), default=None, help="default: 2 px / 0.05"
    )
    p.add_argument(
        "--alphas",
        type=_unit_interval("--alphas"),
        nargs="+",
        default=[0.0, 0.1, 0.5, 0.8, 1.0],
        help="alpha-mix rows (default: 0 0.1 0.5 0.8 1; 0 with rest=all is plain BC)",
    )
    p.add_argument(
        "--readings",
        choices=["all", "noncritical"],
        nargs="+",
        default=["all"],
        help="eq. 5 readings of the alpha rows (default: all; add noncritical for T \\ T_eps)",
    )
    p.add_argument(
        "--baselines",
        choices=list(get_args(Baseline)),
        nargs="*",
        default=list(get_args(Baseline)),
        help="peer-baseline rows (default: both; none with a bare --baselines)",
    )
    p.add_argument(
        "--segment-steps",
        type=_positive("--segment-steps"),
        default=20,
        help="BC-Safe's segment length K in scored steps (default: 20)",
    )
    p.add_argument(
        "--beta",
        type=_non_negative_float("--beta"),
        default=9.0,
        help="cost-weighted BC's strength: weight 1 + beta * closeness to d_s (default: 9)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument(
        "--render-only",
        action="store_true",
        help="rebuild the table and figures from the stored per-episode results",
    )
    p.set_defaults(func=_cmd_reproduce)

    p = sub.add_parser("tune", help="run (or resume) a constrained hyper-parameter study")
    p.add_argument("study", type=Path, help="study file defining STUDY, e.g. tune_jobs/default.py")
    p.add_argument("--trials", type=_positive("--trials"), default=None, help="override")
    p.add_argument("--storage", default=None, help="Tune storage: folder or URI (s3://...)")
    p.add_argument(
        "--threshold",
        type=_finite_float("--threshold"),
        default=None,
        help="safety threshold (default: the expert's safety mean on the demonstrations)",
    )
    p.add_argument(
        "--concurrent", type=_positive("--concurrent"), default=None, help="trials at once"
    )
    p.add_argument(
        "--rollout-workers",
        type=_non_negative_int("--rollout-workers"),
        default=None,
        help="evaluation actors per trial, reserved in its placement group",
    )
    p.add_argument(
        "--cpus-per-trial",
        type=_positive_float("--cpus-per-trial"),
        default=None,
        help="CPUs of a trial's own process (fractional allowed)",
    )
    p.add_argument(
        "--demos", type=Path, default=None, help="demonstration set (a shared path on a cluster)"
    )
    p.add_argument("--results", type=Path, default=None, help="outputs go to RESULTS/<study>/")
    p.add_argument("--fresh", action="store_true", help="discard a previous run of the study")
    p.set_defaults(func=_cmd_tune)

    p = sub.add_parser(
        "improve", help="improve a safety-imitation checkpoint by constrained RL (resumable)"
    )
    p.add_argument("--start", type=Path, required=True, help="a safe-bc train checkpoint")
    p.add_argument("--out", type=Path, required=True, help="run directory (rerun to resume)")
    p.add_argument("--demos", type=Path, default=None, help="default: the start's")
    p.add_argument("--shield", action=argparse.BooleanOptionalAction, default=True,
                   help="imitation start acts in critical states (default: on)")  # fmt: skip
    p.add_argument("--lagrangian", action=argparse.BooleanOptionalAction, default=True,
                   help="PPO-Lagrangian on the violation cost (default: on)")  # fmt: skip
    p.add_argument("--eps", type=_non_negative_float("--eps"), default=None,
                   help="shield's critical-zone width (default: the start's)")  # fmt: skip
    # unset options keep ImproveConfig's defaults (safe_bc/improve/config.py documents each)
    for flag, check, field in (
        ("--cost-signal", ["indicator", "excursion"], "cost_signal"),
        ("--cost-margin", _non_negative_float, "cost_margin"),
        ("--cost-budget", _non_negative_float, "cost_budget"),
        ("--lambda-lr", _non_negative_float, "lambda_lr"),
        ("--anchor", ["bc", "kl", "none"], "anchor"),
        ("--anchor-coef", _non_negative_float, "anchor_coef"),
        ("--iterations", _positive, "iterations"),
        ("--episodes-per-iter", _positive, "episodes_per_iter"),
    ):
        kind = {"choices": check} if isinstance(check, list) else {"type": check(flag)}
        p.add_argument(flag, **kind, default=None, help=_doc(IMPROVE, field))
    p.add_argument("--seed", type=_non_negative_int("--seed"), default=0,
                   help=_doc(IMPROVE, "seed"))  # fmt: skip
    p.add_argument("--rollout-workers", type=_non_negative_int("--rollout-workers"), default=0,
                   help="Ray actors stepping the rollout envs (0: in-process, right for rehab; "
                   "CarRacing: one per core); the run is bit-identical either way")  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_improve)

    p = sub.add_parser("export", help="export a demonstration set to another format (Minari)")
    p.add_argument("--demos", type=Path, default=DEFAULT_DEMOS, help=DEMOS)
    p.add_argument("--format", choices=["minari"], default="minari", help="target format")
    p.add_argument(
        "--dataset-id",
        required=True,
        help="e.g. safe_bc/carracing-drift-v0; written under $MINARI_DATASETS_PATH "
        "(default ~/.minari/datasets)",
    )
    p.add_argument("--author", default=None, help="recorded in the Minari metadata")
    p.set_defaults(func=_cmd_export)

    p = sub.add_parser(
        "render", help="video of a CarRacing episode with the safety rays drawn in (or --paths)"
    )
    p.add_argument("--checkpoint", type=Path, default=None, help="the agent (safe-bc train)")
    p.add_argument("--expert", action="store_true", help="render the expert instead")
    p.add_argument(
        "--paths",
        action="store_true",
        help="draw the track map with the driven paths (expert beside agent) to --out",
    )
    p.add_argument("--seed", type=_non_negative_int("--seed"), default=0, help="track seed")
    p.add_argument("--out", type=Path, required=True, help=".mp4, .gif, or .png with --paths")
    p.add_argument("--max-steps", type=_positive("--max-steps"), default=None, help=MAX_STEPS)
    p.add_argument(
        "--demos",
        type=Path,
        default=None,
        help="expert and limits d_s (default: the checkpoint's, else data/demos)",
    )
    p.add_argument(
        "--eps",
        type=_non_negative_float("--eps"),
        default=None,
        help="critical-zone width (default: the checkpoint's, else 2 px)",
    )
    p.add_argument("--scale", type=_positive("--scale"), default=4, help="upscaling of frames")
    p.add_argument("--fps", type=_positive_float("--fps"), default=50.0,
                   help="frames per second of the video")  # fmt: skip
    p.set_defaults(func=_cmd_render)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point: parse, run, turn expected failures into one-line errors."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if args.command in RAY_COMMANDS and check_ray_address() is not None:
            # join the cluster before anything is written (a refused address fails in
            # milliseconds, something that is not Ray within ~40 s)
            from safe_bc.distributed.runtime import ensure_ray

            ensure_ray()
        return args.func(args)
    except (
        DatasetError,
        ValueError,
        FileNotFoundError,
        CheckpointError,
        RayUnavailableError,
        OutputLockedError,
    ) as e:
        print(f"safe-bc {args.command}: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:  # writing an output: a full disk, a read-only mount, a file in the way
        out = getattr(args, "out", None)
        where = f"{e.filename}: " if e.filename else f"writing {out}: " if out else ""
        detail = e.strerror or " ".join(str(e).split())
        print(f"safe-bc {args.command}: error: {where}{detail}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(
            f"safe-bc {args.command}: interrupted; rerun the same command to resume",
            file=sys.stderr,
        )
        return 130


if __name__ == "__main__":
    sys.exit(main())
