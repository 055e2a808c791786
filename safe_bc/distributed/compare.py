"""Running a :class:`~safe_bc.compare.Comparison`: train, improve, evaluate, write; resumable.

Per (method, training seed) one folder ``OUT/<name>_runs/<method>/seed<k>/``:

* ``agent/``: a BC row's agent, written like ``safe-bc train`` writes a checkpoint (weights,
  config with the run, ``selection.parquet``), so it can start an improvement run;
* ``improve/``: an improvement row's run (:func:`safe_bc.improve.improve`, itself resumable);
* ``episodes.parquet`` (and ``steps.parquet`` for the ``traces`` rows): its evaluation,
  stamped with the run and the evaluation settings.

A rerun reuses every folder whose stamp matches and trains, improves or evaluates only the
rest, so an interrupted comparison resumes where it stopped; a changed setting redoes the
cells it changes. Every policy goes through the one evaluation path
(:func:`safe_bc.distributed.evaluate.evaluate_policies`), all missing ones in one call.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from safe_bc.atomic import write_text_atomic
from safe_bc.compare import (
    EXPERT,
    PAPER_TABLE1,
    Comparison,
    Method,
    build_table,
    render_markdown,
    run_slug,
)
from safe_bc.data.store import load_demonstrations, read_table, write_table_atomic
from safe_bc.evaluation import EvalConfig, ExpertSource, NetSource
from safe_bc.experiment import RunConfig, save_selection, select_for
from safe_bc.metrics import combined
from safe_bc.provenance import run_metadata
from safe_bc.selection import SelectionConfig
from safe_bc.tasks import dataset_action_bounds, task_defaults


def _json(x: Any) -> Any:
    return json.loads(json.dumps(x, default=str))


def run_config(comparison: Comparison, method: Method, seed: int) -> RunConfig:
    """A BC row's training run for ``seed``."""
    assert method.selection is not None
    bc = method.bc or comparison.bc
    return RunConfig(
        method.selection, dataclasses.replace(bc, train=dataclasses.replace(bc.train, seed=seed))
    )


def eval_config(comparison: Comparison) -> EvalConfig:
    """The held-out tracks every policy runs on."""
    return EvalConfig(
        episodes=comparison.episodes,
        workers=comparison.workers,
        seed=comparison.eval_seed,
        env=task_defaults(comparison.task).env,
        max_steps=comparison.max_steps,
        eps=selection_eps(comparison),
    )


def selection_eps(comparison: Comparison) -> float:
    """``eps``, or the task's."""
    return task_defaults(comparison.task).eps if comparison.eps is None else comparison.eps


def _cells(comparison: Comparison) -> list[tuple[Method, int]]:
    return [
        (m, 0 if m.expert else s)
        for m in comparison.methods
        for s in ((0,) if m.expert else comparison.train_seeds)
    ]


def _folder(comparison: Comparison, method: Method, seed: int) -> Path:
    base = comparison.out / f"{comparison.name}_runs" / run_slug(method.name)
    return base if method.expert else base / f"seed{seed}"


def _stamp(comparison: Comparison, method: Method, seed: int, thresholds: Any) -> dict[str, Any]:
    """What a stored evaluation must match to be reused."""
    settings = dataclasses.asdict(eval_config(comparison))
    settings.pop("workers")  # where episodes run changes nothing
    if method.kind == "bc":
        run: Any = run_config(comparison, method, seed).to_dict()
    elif method.kind == "improve":
        assert method.improve is not None
        start = run_config(comparison, comparison.method(method.start), seed).to_dict()
        run = {"start": start, "improve": dataclasses.replace(method.improve, seed=seed).to_dict()}
    else:
        run = {"expert": str(comparison.demos)}
    return _json(
        {
            "run": run,
            "eval": settings,
            "thresholds": [float(x) for x in thresholds],
            "keep_steps": method.name in comparison.traces and seed == comparison.train_seeds[0],
        }
    )


def _stored(folder: Path, stamp: dict[str, Any]) -> pd.DataFrame | None:
    path = folder / "episodes.parquet"
    if not path.exists():
        return None
    frame, meta = read_table(path)
    return frame if meta.get("stamp") == stamp else None


def _agent_ok(folder: Path, run: RunConfig) -> bool:
    from safe_bc.bc import read_checkpoint_meta

    try:
        meta = read_checkpoint_meta(folder)
    except Exception:  # absent or torn: train again
        return False
    return meta.get("extra", {}).get("run") == _json(run.to_dict())


def run_comparison(
    comparison: Comparison, *, progress: bool = True, command: str | None = None
) -> pd.DataFrame:
    """Train, improve and evaluate what is missing, then write every output (module doc).

    Returns:
        The table (:func:`safe_bc.compare.build_table`).
    """
    from safe_bc.bc import load_checkpoint
    from safe_bc.bc.checkpoint import checkpoint_unit
    from safe_bc.collection import stored_expert_config
    from safe_bc.distributed.collect import ensure_demos
    from safe_bc.distributed.evaluate import LOCKSTEP_ENVS, evaluate_policies
    from safe_bc.distributed.train import train_many

    started = time.perf_counter()
    c = comparison
    task = task_defaults(c.task)
    ensure_demos(c.demos, task.collect_config(), progress=progress)
    demos = load_demonstrations(c.demos)
    meta = run_metadata(
        config=_json(c.to_dict()), train_seeds=list(c.train_seeds), eval_seed=c.eval_seed
    )
    if command is not None:
        meta["command"] = command
    c.out.mkdir(parents=True, exist_ok=True)
    eps = selection_eps(c)
    base = select_for(demos, SelectionConfig(eps=eps, alpha=0.0))
    save_selection(c.out / f"{c.name}_selection", demos, base, meta)
    bounds = dataset_action_bounds(c.demos)

    # 1. BC agents not on disk (fail fast on an impossible rule before any training)
    cells = _cells(c)
    todo = [
        (m, s, run_config(c, m, s))
        for m, s in cells
        if m.kind == "bc" and not _agent_ok(_folder(c, m, s) / "agent", run_config(c, m, s))
    ]
    for _m, _, run in todo:
        select_for(demos, run.selection).sampler(run.bc.train.batch_size, np.random.default_rng(0))
    if progress:
        print(f"compare {c.name}: {len(cells)} cells, training {len(todo)} agents")
    trained = train_many(
        demos, [r for *_, r in todo], workers=max(c.workers, 1), action_bounds=bounds,
        progress=progress,
    )  # fmt: skip
    env_id = task.env.env_id
    for (m, s, run), (result, selection) in zip(todo, trained, strict=True):
        train_row = {
            "final_loss": result.final_loss,
            "samples_per_s": result.samples_per_s,
            "n_critical": selection.n_critical,
            "n_train_rows": selection.n_train_rows,
            "critical_sample_share": selection.critical_sample_share,
        }
        agent_meta = _json(
            run_metadata(
                demos=str(c.demos), env_id=env_id, run=run.to_dict(), train=result.summary(),
                train_row=train_row,
            )
        )  # fmt: skip
        with checkpoint_unit(_folder(c, m, s) / "agent") as unit:
            result.save(unit, extra=agent_meta)
            save_selection(unit, demos, selection, agent_meta)

    # 2. improvement runs (each resumes itself), one after the other in the driver
    histories = []
    for m, s in cells:
        if m.kind != "improve":
            continue
        from safe_bc.improve import improve

        assert m.improve is not None
        start = _folder(c, c.method(m.start), s) / "agent"
        done = improve(
            start, _folder(c, m, s) / "improve", dataclasses.replace(m.improve, seed=s),
            demos=c.demos, metadata={"command": meta["command"]},
        )  # fmt: skip
        histories.append(done.history.assign(method=m.name, train_seed=s))

    # 3. evaluation of the cells without a matching stored one, in one call
    sources: dict[str, Any] = {}
    stamps: dict[str, tuple[Method, int, dict[str, Any]]] = {}
    stored: dict[str, pd.DataFrame] = {}
    for m, s in cells:
        key = EXPERT if m.expert else f"{m.name} seed={s}"
        stamp = _stamp(c, m, s, base.thresholds)
        stamps[key] = (m, s, stamp)
        have = _stored(_folder(c, m, s), stamp)
        if have is not None:
            stored[key] = have
        elif m.expert:
            sources[key] = ExpertSource(stored_expert_config(c.demos))
        elif m.kind == "bc":
            sources[key] = NetSource.from_model(*load_checkpoint(_folder(c, m, s) / "agent"))
        else:
            from safe_bc.improve import ImprovedSource

            sources[key] = ImprovedSource.from_run(_folder(c, m, s) / "improve")
    if progress:
        print(f"compare {c.name}: evaluating {len(sources)} of {len(stamps)} policies")
    if sources:
        episodes, steps = evaluate_policies(
            sources, eval_config(c), thresholds=base.thresholds, progress=progress,
            envs_per_worker=LOCKSTEP_ENVS,
        )  # fmt: skip
        for key in sources:
            m, s, stamp = stamps[key]
            folder = _folder(c, m, s)
            cell_meta = {**meta, "stamp": stamp}
            ep = episodes[episodes["policy"] == key].reset_index(drop=True)
            if stamp["keep_steps"]:
                st = steps[steps["policy"] == key].reset_index(drop=True)
                write_table_atomic(folder / "steps.parquet", st, cell_meta)
            write_table_atomic(folder / "episodes.parquet", ep, cell_meta)
            stored[key] = ep

    # 4. the tables, in spec order
    parts, traces, train_rows = [], [], []
    for key, (m, s, stamp) in stamps.items():
        labels = {**m.labels, "train_seed": s}
        ep = stored[key]
        parts.append(
            pd.DataFrame({"policy": ep["policy"], **labels}).join(ep.drop(columns="policy"))
        )
        if stamp["keep_steps"]:
            traces.append(read_table(_folder(c, m, s) / "steps.parquet")[0])
        if m.kind == "bc":
            from safe_bc.bc import read_checkpoint_meta

            extra = read_checkpoint_meta(_folder(c, m, s) / "agent")["extra"]
            train_rows.append({**labels, **extra["train_row"]})
    episodes = pd.concat(parts, ignore_index=True)
    steps = pd.concat(traces, ignore_index=True) if traces else pd.DataFrame()
    train_df = pd.DataFrame(train_rows)
    meta["seconds"] = round(time.perf_counter() - started, 1)
    meta["demo_safety_mean"] = float(combined(demos.safety[demos.scored]).mean())
    write_table_atomic(c.out / f"{c.name}_episodes.parquet", episodes, meta)
    write_table_atomic(c.out / f"{c.name}_traces.parquet", steps, meta)
    write_table_atomic(c.out / f"{c.name}_training.parquet", train_df, meta)
    if histories:
        history = pd.concat(histories, ignore_index=True)
        write_table_atomic(c.out / f"{c.name}_history.parquet", history, meta)
    return write_outputs(c, episodes, steps, train_df, meta)


def write_outputs(
    comparison: Comparison,
    episodes: pd.DataFrame,
    traces: pd.DataFrame,
    train_df: pd.DataFrame,
    meta: dict[str, Any],
) -> pd.DataFrame:
    """The table, its Markdown and the figures from per-episode results."""
    c = comparison
    table = build_table(c, episodes, train_df)
    write_table_atomic(c.out / f"{c.name}.parquet", table, meta)
    write_text_atomic(c.out / f"{c.name}.md", render_markdown(c, table, meta))
    from safe_bc.plots import plot_alpha_sweep, plot_traces

    for figure, file in c.figures:
        if figure == "alpha_sweep":
            sweep = table[table["mode"].isin(["mix", EXPERT])]  # the baselines have no alpha
            plot_alpha_sweep(sweep, c.out / file, paper=PAPER_TABLE1 if c.paper else None)
        elif figure == "traces" and len(traces):
            pairs = episodes[["policy", "method"]].drop_duplicates().values
            plot_traces(traces, {p: {"method": m} for p, m in pairs}, c.out / file)
    return table


def rerender(comparison: Comparison) -> pd.DataFrame:
    """Rebuild the table, its Markdown and figures from the stored per-episode results.

    Nothing is trained or evaluated again; the metadata keeps the original run's command and
    revision and adds the re-rendering's under ``rendered``.
    """
    c = comparison
    episodes, meta = read_table(c.out / f"{c.name}_episodes.parquet")
    traces, _ = read_table(c.out / f"{c.name}_traces.parquet")
    training = c.out / f"{c.name}_training.parquet"
    if training.exists():
        train_df, _ = read_table(training)
    else:  # runs before the training table existed kept these columns in the table
        old, _ = read_table(c.out / f"{c.name}.parquet")
        train_df = old[["method", "final_loss", "samples_per_s"]].dropna()
    meta = {**meta, "rendered": run_metadata()}
    return write_outputs(c, episodes, traces, train_df, meta)
