"""What each ``safe-bc`` command does, callable from scripts: a function per command taking
its :mod:`safe_bc.cli.jobs` record and returning a :class:`Done` (the CLI prints its message and
exits with its code)."""

from __future__ import annotations

import fnmatch
import functools
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from safe_bc.cli.jobs import (
    CollectJob,
    CompareJob,
    DescribeJob,
    EvaluateJob,
    ExpertJob,
    ExportJob,
    MethodJob,
    RenderJob,
    ReproduceJob,
    TrainJob,
    TuneJob,
)
from safe_bc.data.locks import check_output_folder, output_lock, output_locks


@dataclass(frozen=True)
class Done:
    """What a command did."""

    message: str
    """The summary ``safe-bc`` prints."""
    value: Any = None
    """The command's result (e.g. the training result and selection of ``train``)."""
    code: int = 0
    """Exit code: 0 done, 1 done without a usable result, 130 interrupted (resumable)."""


def collect(job: CollectJob) -> Done:
    """Collect (or complete) a demonstration set; the value is the collection report."""
    from safe_bc.distributed.collect import collect as run_collect
    from safe_bc.rollout.collect import CollectConfig
    from safe_bc.tasks import task_defaults

    task = task_defaults(job.env, renderer=job.renderer)
    out = job.out or Path(task.demos)
    given = {k: getattr(job, k) for k in ("episodes", "workers", "seed", "encoding")}
    config = CollectConfig.for_task(
        task, max_steps=job.max_steps, **{k: v for k, v in given.items() if v is not None}
    )
    report = run_collect(config, out, progress=not job.quiet)
    return Done(
        f"{out}: {len(report.collected)} episode(s) collected, {len(report.reused)} reused, "
        f"{report.steps} steps in {report.seconds:.1f} s ({report.steps_per_s:.0f} steps/s), "
        f"{report.worker_restarts} worker restart(s)",
        report,
    )


def describe(job: DescribeJob) -> Done:
    """Cost histograms and ``summary.json`` of a demonstration set (the value)."""
    from safe_bc.data.atomic import write_json_atomic
    from safe_bc.data.provenance import command_line, provenance
    from safe_bc.data.store import data_digest, load_demonstrations, read_episodes, read_meta
    from safe_bc.methods.experiment import select_for
    from safe_bc.metrics import combined
    from safe_bc.plots import plot_cost_histograms
    from safe_bc.selection import SelectionConfig
    from safe_bc.tasks import task_defaults, task_of

    check_output_folder(job.out)
    demos = load_demonstrations(job.demos)
    meta = read_meta(job.demos)
    task = task_defaults(task_of(meta.env_id))
    eps = task.eps if job.eps is None else job.eps
    sel = select_for(demos, SelectionConfig(eps=eps, alpha=0.0))
    scored = demos.scored
    offroad = sum(int(ep.offroad.sum()) for ep in read_episodes(job.demos))
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
        "demos": str(job.demos),
        "digest": data_digest(job.demos),
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
        "eps": eps,
        "critical_pairs": int(sel.n_critical),
        "critical_share": float(sel.n_critical / sel.n_valid),
        "selection": sel.to_dict(),
        "dataset": json.loads(meta.to_json()),
        "described_by": {"command": command_line(), "provenance": provenance()},
    }
    job.out.mkdir(parents=True, exist_ok=True)
    title = f"{job.demos}: {len(demos)} pairs, {summary['digest'][:19]}"
    plot_cost_histograms(
        demos, job.out / "cost_histograms.png", eps=eps, title=title, units=task.safety_units
    )
    write_json_atomic(job.out / "summary.json", summary)
    keys = ("pairs", "episodes", "safety_mean", "offroad_frames", "critical_share")
    lines = [json.dumps({k: summary[k] for k in keys})]
    lines += [
        f"{d:>6}: d_s {v['d_s']:.2f} of {v['max_cost']:.2f} (closest distance "
        f"{v['closest_distance']:.2f}), critical pairs at eps {eps:g}: {v['critical_pairs']}"
        for d, v in limits.items()
    ]
    lines.append(f"wrote {job.out / 'cost_histograms.png'} and {job.out / 'summary.json'}")
    return Done("\n".join(lines), summary)


def train(job: TrainJob) -> Done:
    """Select ``T_eps`` and train one agent into the checkpoint ``job.out`` (whole or not at
    all); a ``job.run.selection.eps`` left unset is the demonstrations' task's
    (``TaskSpec.eps``). The value is ``(TrainResult, Selection)``."""
    with output_lock(job.out):
        return _train(job)


def _train(job: TrainJob) -> Done:
    from safe_bc.bc.checkpoint import checkpoint_unit
    from safe_bc.data.curves import EVENTS_GLOB
    from safe_bc.data.demos import hold_out_episodes
    from safe_bc.data.provenance import run_metadata
    from safe_bc.data.store import check_dataset, load_demonstrations, read_meta
    from safe_bc.methods.experiment import save_curve, save_selection, train_run
    from safe_bc.tasks import dataset_action_bounds, with_task_eps

    check_dataset(job.demos)  # a damaged set is refused before its frame cache is made
    demos = load_demonstrations(job.demos)
    env_id = read_meta(job.demos).env_id
    run = with_task_eps(job.run, env_id)
    bounds = dataset_action_bounds(job.demos)
    held = {}
    validation = None
    if job.validation_episodes:
        demos, validation = hold_out_episodes(demos, job.validation_episodes)
        held = {"validation_episodes": sorted(int(i) for i in set(validation.episode_ids))}
    result, selection = train_run(
        demos, run, progress=not job.quiet, action_bounds=bounds, validation=validation
    )
    meta = run_metadata(
        demos=str(job.demos), env_id=env_id, run=run.to_dict(), train=result.summary(), **held
    )
    before = set(os.listdir(job.out)) if job.out.is_dir() else set()
    with checkpoint_unit(job.out) as unit:  # weights, config, selection, curve: old or new
        result.save(unit, extra=json.loads(json.dumps(meta, default=str)))
        save_selection(unit, demos, selection, meta)
        save_curve(unit, result, meta)
    after = set(os.listdir(job.out))
    dropped = sorted(n for n in before - after if not fnmatch.fnmatch(n, EVENTS_GLOB))
    note = f"; removed {', '.join(dropped)}, evaluated other weights" if dropped else ""
    val = "" if result.val_losses is None else f" (validation {result.val_losses[-1]:.4f})"
    return Done(
        f"{job.out}: trained {run.bc.train.batches} batches, final loss "
        f"{result.final_loss:.4f}{val}, {result.samples_per_s:.0f} samples/s; "
        f"|T_eps| = {selection.n_critical} of {selection.n_valid} scored pairs{note}",
        (result, selection),
    )


def evaluate(job: EvaluateJob) -> Done:
    """Evaluate a checkpoint on held-out episodes; the value is the evaluation result. One
    process writes ``job.out`` at a time (its output lock)."""
    with output_lock(job.out):
        return _evaluate(job)


def _evaluate(job: EvaluateJob) -> Done:
    import numpy as np

    from safe_bc.bc import load_checkpoint, read_checkpoint_meta
    from safe_bc.bc.checkpoint import EVALUATED_WEIGHTS
    from safe_bc.data.provenance import run_metadata
    from safe_bc.data.store import read_table, write_table_atomic
    from safe_bc.distributed.evaluate import evaluate as run_evaluate
    from safe_bc.metrics import METRICS
    from safe_bc.report import estimate_lines
    from safe_bc.rollout.evaluate import EvalConfig, NetSource
    from safe_bc.tasks import check_net_fits_task, task_defaults, task_of

    if job.recommender is not None:
        return evaluate_recommender(job)
    if job.checkpoint is None:
        raise ValueError("evaluate needs --checkpoint DIR (an agent) or --recommender DIR")
    model, bc_cfg = load_checkpoint(job.checkpoint)
    checkpoint_meta = read_checkpoint_meta(job.checkpoint)
    extra = checkpoint_meta.get("extra", {})
    _, sel_meta = read_table(job.checkpoint / "selection.parquet")
    if "env_id" not in extra:
        raise ValueError(f"{job.checkpoint}: no env_id in the checkpoint; train with safe-bc train")
    spec = model.spec
    check_net_fits_task(spec.obs_shape, spec.action_dim, extra["env_id"], job.checkpoint)
    task = task_defaults(task_of(extra["env_id"]))
    sel_cfg = sel_meta.get("config", {})
    cfg = EvalConfig(
        episodes=job.episodes,
        workers=job.workers,
        seed=job.eval_seed,
        env=task.env,
        max_steps=job.max_steps,
        eps=float(sel_cfg.get("eps", task.eps)),
        combine=sel_cfg.get("combine", "any"),
    )
    thresholds = np.asarray(sel_meta["thresholds"])
    agent: Any = NetSource.from_model(model, bc_cfg)
    h = job.handover  # its own checks ran when the job was made (HandoverFlags)
    if h.width is not None:
        from safe_bc.rollout.collect import expert_for
        from safe_bc.rollout.handover import DeferralSource, dimension_indices

        hold_on = dimension_indices(h.hold_on, task.safety_dims)
        expert_cfg = expert_for(extra.get("demos", ""), extra["env_id"])
        agent = DeferralSource(
            agent, expert_cfg, tuple(float(x) for x in thresholds), h.width, cfg.combine,
            h.hold, h.lookahead, hold_on,
        )  # fmt: skip
    result = run_evaluate({"agent": agent}, cfg, thresholds, progress=not job.quiet)
    episodes, steps, table = result.episodes, result.steps, result.summary
    meta = run_metadata(
        checkpoint=str(job.checkpoint),
        defer_width=h.width,
        defer_hold=h.hold,
        defer_lookahead=h.lookahead,
        defer_hold_on=list(h.hold_on),
        trained_with=extra.get("run"),
        eval_seed=job.eval_seed,
        env_seeds=episodes["env_seed"].tolist(),
        **{EVALUATED_WEIGHTS: checkpoint_meta.get("weights_sha256")},
    )
    job.out.mkdir(parents=True, exist_ok=True)
    write_table_atomic(job.out / "episodes.parquet", episodes, meta)
    write_table_atomic(job.out / "steps.parquet", steps, meta)
    write_table_atomic(job.out / "summary.parquet", table, meta)
    lines = estimate_lines(table.iloc[0], [m for m in METRICS if m in table], len(episodes))
    if h.width is not None:
        share = float(episodes["deferred_share"].mean())
        lines.append(
            f"deferred to the expert within {h.width:g} of d_s"
            + (f" (held {h.hold} steps)" if h.hold else "")
            + (f" after {', '.join(h.hold_on)}" if h.hold_on else "")
            + (f" ({h.lookahead} steps ahead)" if h.lookahead else "")
            + f": {share:.1%} of steps"
        )
    lines.append(f"wrote {job.out}/episodes.parquet, steps.parquet, summary.parquet")
    return Done("\n".join(lines), result)


def evaluate_recommender(job: EvaluateJob) -> Done:
    """``safe-bc evaluate --recommender DIR``: every training seed's agent of a study's
    recommender with its handover, on the same held-out tracks (a crossed seeds x tracks
    design), at the recommender's own ``d_s``."""
    import numpy as np

    from safe_bc.data.provenance import run_metadata
    from safe_bc.data.store import write_table_atomic
    from safe_bc.distributed.evaluate import evaluate as run_evaluate
    from safe_bc.metrics import certified_share, episodes_beyond
    from safe_bc.rollout.evaluate import EvalConfig
    from safe_bc.study.recommender import load_recommender
    from safe_bc.tasks import task_defaults

    if job.handover.given:
        raise ValueError("--handover.* flags do not apply to --recommender (it has its handover)")
    if job.checkpoint is not None:
        raise ValueError("give --checkpoint or --recommender, not both")
    assert job.recommender is not None
    rec = load_recommender(job.recommender)
    seeds = rec.card.seeds if job.recommender_seed is None else [job.recommender_seed]
    task = task_defaults(rec.card.task)
    handover = rec.card.handover_config
    cfg = EvalConfig(
        episodes=job.episodes, workers=job.workers, seed=job.eval_seed, env=task.env,
        max_steps=job.max_steps, eps=task.eps if handover is None else handover.width,
    )  # fmt: skip
    sources = {f"recommender seed={s}": rec.source(s) for s in seeds}
    result = run_evaluate(sources, cfg, np.asarray(rec.limits), progress=not job.quiet)
    episodes, steps, table = result.episodes, result.steps, result.summary
    meta = run_metadata(
        recommender=str(job.recommender),
        recommender_card={k: rec.card.to_dict()[k] for k in ("task", "limits", "handover",
                                                             "demos", "seeds", "source")},
        eval_seed=job.eval_seed,
        env_seeds=sorted(set(episodes["env_seed"].tolist())),
    )  # fmt: skip
    job.out.mkdir(parents=True, exist_ok=True)
    write_table_atomic(job.out / "episodes.parquet", episodes, meta)
    write_table_atomic(job.out / "steps.parquet", steps, meta)
    write_table_atomic(job.out / "summary.parquet", table, meta)
    beyond = int(episodes_beyond(episodes).sum())
    deferred = (
        f", {100 * episodes['deferred_share'].mean():.1f}% of steps handed over"
        if "deferred_share" in episodes
        else ""
    )
    lines = [
        f"recommender {job.recommender} ({len(seeds)} training seed(s) x {job.episodes} "
        f"{task.episodes_name} "
        f"of block {job.eval_seed}): reward {episodes['reward'].mean():.1f}, safety mean "
        f"{episodes['safety_mean'].mean():.2f}; {certified_share(beyond, len(episodes))}"
        + deferred,
        f"wrote {job.out}/episodes.parquet, steps.parquet, summary.parquet",
    ]
    return Done("\n".join(lines), result)


def expert(job: ExpertJob) -> Done:
    """Measure the task's expert on held-out episodes (``expert.md``, the message)."""
    from safe_bc.data.atomic import write_text_atomic
    from safe_bc.data.provenance import run_metadata
    from safe_bc.data.store import read_demonstrations, write_table_atomic
    from safe_bc.distributed.collect import ensure_demos
    from safe_bc.distributed.evaluate import evaluate as run_evaluate
    from safe_bc.metrics import METRICS
    from safe_bc.report import MIN_EPISODES_FOR_INTERVAL, markdown_table
    from safe_bc.rollout.collect import CollectConfig
    from safe_bc.rollout.evaluate import EvalConfig, ExpertSource
    from safe_bc.tasks import task_defaults

    check_output_folder(job.out)
    task = task_defaults(job.env)
    demos_path = job.demos or Path(task.demos)
    if job.demos is None:  # the task's own set, built if absent; a given set is used as it is
        ensure_demos(demos_path, CollectConfig.for_task(task), progress=not job.quiet)
    demos, record = read_demonstrations(demos_path)
    limits = demos.limits
    cfg = EvalConfig(
        episodes=job.episodes, workers=job.workers, seed=job.eval_seed, env=task.env, eps=task.eps
    )
    result = run_evaluate(
        {"expert": ExpertSource(task.expert)}, cfg, limits, progress=not job.quiet
    )
    episodes, table = result.episodes, result.summary
    metrics = [m for m in METRICS if m in table]
    metrics += [c for c in table.columns if c.startswith("safety_") and c.endswith("_mean")]
    metrics = list(dict.fromkeys(metrics))
    meta = run_metadata(
        expert=repr(task.expert),
        env=job.env,
        episodes=job.episodes,
        eval_seed=job.eval_seed,
        env_seeds=episodes["env_seed"].tolist(),
        demos=str(demos_path),
        inputs={"demos": record},
        limits=[float(x) for x in limits],
        eps=task.eps,
    )
    job.out.mkdir(parents=True, exist_ok=True)
    write_table_atomic(job.out / "expert_episodes.parquet", episodes, meta)
    write_table_atomic(job.out / "expert.parquet", table, meta)
    r = table.iloc[0]
    dims = ", ".join(f"{d} {x:.2f}" for d, x in zip(demos.safety_dims, limits, strict=True))
    if len(episodes) < MIN_EPISODES_FOR_INTERVAL:
        cells = [[m, f"{r[m]:.2f}"] for m in metrics]
        lines = [markdown_table(cells, ["metric", "mean"]), "", "too few episodes for an interval"]
    else:
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
    text = "\n".join(lines)
    write_text_atomic(job.out / "expert.md", text)
    return Done(text, result)


def reproduce(job: ReproduceJob) -> Done:
    """Rerun Table 1 (or, ``render_only``, rebuild it from stored results); the value is the
    table."""
    from safe_bc.compare.reproduce import rerender, run_reproduce

    config = job.config
    check_output_folder(config.out)
    table = rerender(config) if job.render_only else run_reproduce(config, progress=not job.quiet)
    cols = ["method", "reward", "safety_mean", "safety_std", "offroad_steps"]
    text = table[cols].to_string(index=False, float_format=lambda x: f"{x:.2f}")
    return Done(f"{text}\nwrote {config.out / 'table1.parquet'} and {config.out / 'table1.md'}")


def compare(job: CompareJob) -> Done:
    """Run (or resume, or ``render_only`` rebuild, or ``report_only`` report) the comparison
    ``job.name`` of the family file ``job.comparison``."""
    from safe_bc.compare.families import load_comparison
    from safe_bc.compare.run import rerender, run_cell, run_comparison, run_report

    comparison = load_comparison(job.comparison, job.name)
    check_output_folder(comparison.out)
    if job.workers is not None and job.cell is None:
        raise ValueError("--workers only applies with --cell")
    if job.report_only:
        if job.render_only or job.cell is not None:
            raise ValueError("--report-only runs the report step alone (no --render-only, --cell)")
        if comparison.report is None:
            raise ValueError(f"comparison {comparison.name!r} declares no report step")
        return Done("wrote " + ", ".join(map(str, run_report(comparison))), comparison)
    if job.cell is not None:
        folder = run_cell(comparison, job.cell, workers=job.workers, progress=not job.quiet)
        return Done(f"cell {job.cell} done in {folder}", comparison)
    if job.render_only:
        rerender(comparison)
    else:
        run_comparison(comparison, progress=not job.quiet)
    return Done(f"wrote {comparison.out / (comparison.name + '.parquet')} and .md", comparison)


def tune(job: TuneJob, *, command: str = "", callbacks: Sequence[Any] = ()) -> Done:
    """Run (or resume) the study of ``job.study`` with ``job``'s overrides (or its
    ``replicates``); the value is the study outcome; its code is the outcome's ``exit_code``
    (1 without a winner, 130 for an incomplete study).

    ``callbacks``: Ray Tune callbacks (``ray.tune.Callback``) that join the study's Tune run
    beside ``job.tracker``'s (e.g. a tracker of your own; docs/curves.md).

    Raises:
        StudyStopped: Ctrl-C or SIGTERM stopped the study (a ``KeyboardInterrupt`` whose
            ``exit_code`` is 130 or 143), once what finished is written: rerun to resume.
    """
    import shlex

    from safe_bc.overrides import apply_overrides
    from safe_bc.study.console import one_line_warnings
    from safe_bc.study.plan import experiment_location
    from safe_bc.study.run import format_outcome, run_study
    from safe_bc.study.spec import load_study

    spec = replace(load_study(job.study), **job.overrides())
    for path, value in job.spec_overrides():
        try:
            spec = apply_overrides(spec, [(path, value)])
        except ValueError as e:
            raise ValueError(f"--set {path}={value}: {e}") from None
    spec = replace(spec, trials=spec.trials + job.more_trials)
    from safe_bc.study.trackers import check_tracker, tracker_callbacks

    check_tracker(job.tracker)  # a missing package: one line before anything starts
    if job.replicates is not None and (job.tracker != "none" or callbacks):
        raise ValueError("--tracker and callbacks apply to one study run, not to --replicates")
    if job.replicates is not None:  # it prints its table and verdict itself
        from safe_bc.study.run_replicates import tune_replicates

        argv = shlex.split(command) or ["safe-bc", "tune", str(job.study)]
        return Done("", code=tune_replicates(spec, job.replicates, fresh=job.fresh, argv=argv))
    _check_study_demos(spec)
    # one study run per results folder and per (local) Tune experiment folder
    storage, experiment = experiment_location(spec)
    outputs = [(spec.results / spec.name, "--results")]
    if "://" not in storage:
        outputs.append((Path(experiment), "--storage"))
    trackers = tracker_callbacks(job.tracker, spec.name, spec.results / spec.name)
    with output_locks(outputs), one_line_warnings():
        outcome = run_study(
            spec, fresh=job.fresh, command=command, verbose=job.verbose,
            callbacks=[*trackers, *callbacks],
        )  # fmt: skip
    if outcome.stopped_by:  # what finished is written; the stop is one line, not a summary
        from safe_bc.study.stop import StudyStopped

        raise StudyStopped(outcome.stopped_by)
    return Done(format_outcome(outcome, spec.params), outcome, outcome.exit_code)


def _check_study_demos(spec: Any) -> None:
    """A study's demonstrations, where they exist, are a whole set (checked before Ray
    starts); a missing folder is collected by the study."""
    from safe_bc.data.store import check_dataset

    for path in (spec.demos, spec.validation_demos):
        if path is not None and Path(path).exists():
            check_dataset(Path(path), "--demos" if path == spec.demos else "--validation-demos")


def method(job: MethodJob) -> Done:
    """Run (or resume) the registered method ``job.name`` from a checkpoint; the value is its
    :class:`~safe_bc.methods.Improved`."""
    from dataclasses import replace

    from safe_bc.distributed.rollouts import ChunkedRayRollouts
    from safe_bc.methods import method_of
    from safe_bc.methods.start import start_from_checkpoint

    spec = method_of(job.name)
    start = replace(start_from_checkpoint(job.start, job.demos), parallel=ChunkedRayRollouts)
    with output_lock(job.out):
        done = spec.run(job.config, start, job.out)
    report = ", ".join(f"{k} {v:g}" for k, v in done.report.items())
    return Done(
        f"{job.out}: {spec.name} from {job.start}" + (f"; {report}" if report else ""), done
    )


def method_command(name: str, job: Any) -> Done:
    """Run ``job`` by the command ``name`` from before ``safe-bc method NAME``
    (:data:`safe_bc.methods.METHOD_COMMANDS`, e.g. ``safe-bc query``), its rollouts on Ray
    actors; the value is the run's result. Each such command is also a function of this module
    by its name (``api.query(job)``)."""
    from safe_bc.distributed.rollouts import ChunkedRayRollouts
    from safe_bc.methods import METHOD_COMMANDS

    run = METHOD_COMMANDS[name].load()
    summary, value = run(job, parallel=ChunkedRayRollouts, envs=_ray_envs)
    return Done(summary, value)


def _ray_envs(workers: int) -> Any:
    """Env groups stepped by ``workers`` Ray actors (imported only when asked for)."""
    from safe_bc.distributed.envs import ray_envs

    return ray_envs(workers)


def __getattr__(name: str) -> Any:
    """A command from before ``safe-bc method NAME`` (:data:`safe_bc.methods.METHOD_COMMANDS`)
    by its name: ``job -> Done``, :func:`method_command`."""
    from safe_bc.methods import METHOD_COMMANDS

    if name not in METHOD_COMMANDS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return functools.partial(method_command, name)


def export(job: ExportJob) -> Done:
    """Export a demonstration set as a Minari dataset (the value)."""
    from safe_bc.data.store import check_dataset
    from safe_bc.export.minari_export import MinariNotInstalledError, export_minari

    check_dataset(job.demos)  # before Minari writes its namespace files
    try:
        dataset = export_minari(
            job.demos, job.dataset_id, author=job.author, eps=job.eps, cost=job.cost
        )
    except MinariNotInstalledError as e:
        raise ValueError(str(e)) from None
    meta = dataset.storage.metadata
    return Done(
        f"{job.demos} -> Minari dataset {job.dataset_id}: {dataset.total_episodes} episode(s), "
        f"{dataset.total_steps} steps in {dataset.storage.data_path.parent}; scalar costs "
        f"({job.cost}, eps {meta['safe_bc_eps']:g}): {meta['safe_bc_cost_steps']} step(s) "
        f"marked; load it with minari.load_dataset({job.dataset_id!r})",
        dataset,
    )


def render(job: RenderJob) -> Done:
    """A video (or, ``paths``, a track map) of one episode with the safety rays drawn in."""
    from safe_bc.render import render_command

    given = {k: getattr(job, k) for k in ("scale", "fps") if getattr(job, k) is not None}
    if job.recommender is not None:
        from safe_bc.render import render_recommender

        if job.checkpoint is not None or job.expert or job.paths:
            raise ValueError("--recommender renders the recommender alone: drop --checkpoint, "
                             "--expert and --paths")  # fmt: skip
        return Done(
            render_recommender(
                job.out,
                job.seed,
                job.recommender,
                agent_seed=job.recommender_seed,
                max_steps=job.max_steps,
                progress=not job.quiet,
                **given,
            )
        )
    return Done(
        render_command(
            job.out,
            job.seed,
            checkpoint=job.checkpoint,
            expert=job.expert,
            paths=job.paths,
            demos=job.demos,
            eps=job.eps,
            max_steps=job.max_steps,
            progress=not job.quiet,
            **given,
        )
    )
