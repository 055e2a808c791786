"""Running a :class:`~safe_bc.compare.spec.Comparison`: train, improve, evaluate, write; resumable.

Per (method, training seed) one folder ``OUT/<runs>_runs/<method>/seed<k>/``:

* ``agent/``: a BC row's agent, written like ``safe-bc train`` writes a checkpoint (weights,
  config with the run, ``selection.parquet``), so it can start an improvement run;
* ``<method>/``: a method row's run (:class:`~safe_bc.compare.rows.FromStart`: the registered
  method's runner from the start row's ``agent/``, itself resumable; e.g. ``improve/``,
  ``selfimprove/``).

Each cell's evaluation is stored by what made it, never by folder:
``OUT/stored_evaluations/<key>.parquet`` (and ``<key>.steps.parquet`` for the ``traces`` rows),
``key`` the content key of its stamp (:func:`cell_stamp`, :mod:`safe_bc.compare.eval_store`: the run
or agent, the tracks, the evaluation settings, the thresholds). Two comparisons needing the
same evaluation share it; two needing different ones never overwrite each other.

A rerun reuses every agent and run whose recorded config matches and every evaluation whose
stamp is stored, and trains, improves or evaluates only the rest, so an interrupted
comparison resumes where it stopped; a changed setting redoes the cells it changes. Every
policy goes through the one evaluation path
(:func:`safe_bc.distributed.evaluate.evaluate_policies`), all missing ones in one call per env
and thresholds. The driver is a plan (:func:`plan_evaluations`, pure), the runs
(:func:`_train_agents`, :func:`_improve_cell`, :func:`_evaluate`) and the report
(:func:`_report`, :func:`write_outputs`, then the comparison's report step,
:func:`run_report`: e.g. the default its table supports). What differs between kinds of row
(the agent it trains, the method it runs, its stamp, its policy) is the row's own
(:class:`~safe_bc.compare.rows.Row`); the runner calls that interface, supplies the effects
(:class:`_Runs`) and never asks a row's kind.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from safe_bc.compare.eval_store import episodes_path, steps_path
from safe_bc.compare.spec import (
    EXPERT,
    PAPER_TABLE1,
    Comparison,
    FromStart,
    Handover,
    Read,
    ReportFiles,
    Row,
    build_table,
    check_report_files,
    machines,
    render_markdown,
    run_slug,
)
from safe_bc.data.atomic import write_text_atomic
from safe_bc.data.provenance import command_line, file_digest, run_metadata
from safe_bc.data.store import (
    read_demonstrations,
    read_meta,
    read_table,
    write_table_atomic,
)
from safe_bc.methods.experiment import RunConfig, save_curve, save_selection, select_for
from safe_bc.methods.registry import SHARED
from safe_bc.metrics import combined
from safe_bc.rollout.collect import CollectConfig
from safe_bc.rollout.evaluate import EvalConfig, ExpertSource, MaskedSource, NetSource
from safe_bc.selection import SelectionConfig
from safe_bc.tasks import check_frames_renderer, dataset_action_bounds, task_defaults
from safe_bc.tasks.env_config import DEFAULT_RENDERER


def _json(x: Any) -> Any:
    return json.loads(json.dumps(x, default=str))


def run_config(comparison: Comparison, method: Row, seed: int) -> RunConfig:
    """A BC row's training run for ``seed`` (:meth:`~safe_bc.compare.rows.Row.agent_run`)."""
    run = method.agent_run(comparison, seed)
    if run is None:
        raise ValueError(f"row {method.name!r} trains no BC agent of its own")
    return run


def eval_config(comparison: Comparison, method: Row | None = None) -> EvalConfig:
    """The held-out tracks every policy runs on, in the env ``method`` is evaluated in (its
    ``renderer``; ``None``: the task's default env)."""
    heldout = comparison.tracks == "heldout"
    renderer = method.renderer if method is not None and method.renderer else DEFAULT_RENDERER
    return EvalConfig(
        episodes=comparison.episodes,
        workers=comparison.workers,
        seed=comparison.eval_seed,
        first_episode=comparison.first_track if heldout else 0,
        env=task_defaults(comparison.task, renderer).env,
        max_steps=comparison.max_steps,
        eps=selection_eps(comparison),
        lockstep_forward=comparison.lockstep_forward,
    )


def track_seeds(comparison: Comparison) -> list[int]:
    """The env seeds every policy runs on (:attr:`Comparison.tracks`)."""
    if comparison.tracks == "heldout":
        return eval_config(comparison).seeds()
    from safe_bc.methods.common import validation_seeds

    first = comparison.first_track
    return validation_seeds(first + comparison.episodes)[first:]


def selection_eps(comparison: Comparison) -> float:
    """``eps``, or the task's (:attr:`Comparison.width`)."""
    return comparison.width


def demos_of(comparison: Comparison, method: Row) -> Path:
    """The demonstrations behind ``method``'s agents (its own ``demos``, those of the row it
    derives from, else the comparison's): its evaluation thresholds are their limits."""
    return method.demos_in(comparison)


def own_demos(comparison: Comparison) -> dict[Path, Any]:
    """Each demonstration set the comparison needs -> the collection it expects (the
    comparison's :attr:`~safe_bc.compare.spec.Comparison.collect`, else the task's default; a BC
    row's own ``demos`` drawn by the row's ``renderer``, also when it is the comparison's set);
    the comparison's set first."""
    task = comparison.task
    out: dict[Path, Any] = {}
    for m in comparison.methods:
        path = m.own_set()
        if path is not None and path not in out:
            renderer = m.renderer or DEFAULT_RENDERER
            if comparison.collect is None:
                out[path] = CollectConfig.for_task(task_defaults(task, renderer))
            else:  # the comparison's collection, drawn by the row's renderer
                env = dataclasses.replace(comparison.collect.env, renderer=renderer)
                out[path] = dataclasses.replace(comparison.collect, env=env)
    own = out.pop(comparison.demos, None)
    first = comparison.collect or own or CollectConfig.for_task(task_defaults(task))
    return {comparison.demos: first, **out}


def run_digests(comparison: Comparison, plan: dict[str, Cell]) -> dict[str, str]:
    """What the tables read, by content: each cell's BC agent (its weights' SHA-256,
    ``<runs>_runs/<row>/seed<k>/agent/``) and its stored evaluation (SHA-256 of
    ``stored_evaluations/<key>.parquet``), keyed by path relative to the comparison's output
    folder."""
    from safe_bc.bc import read_checkpoint_meta

    out: dict[str, str] = {}
    for cell in plan.values():
        folder = _folder(comparison, cell.row, cell.seed)
        if (folder / "agent" / "config.json").is_file():
            weights = read_checkpoint_meta(folder / "agent").get("weights_sha256", "")
            out[str((folder / "agent").relative_to(comparison.out))] = f"sha256:{weights}"
        episodes = episodes_path(comparison.out, cell.stamp)
        if episodes.is_file():
            out[str(episodes.relative_to(comparison.out))] = file_digest(episodes)
    return out


def _cells(comparison: Comparison) -> list[tuple[Row, int]]:
    return [(m, s) for m in comparison.methods for s in comparison.seeds_of(m)]


def _folder(comparison: Comparison, method: Row, seed: int) -> Path:
    stem = comparison.runs or comparison.name
    return method.cell_folder(comparison.out / f"{stem}_runs" / run_slug(method.name), seed)


def shared_folder(comparison: Comparison) -> Path:
    """Where the runs of ``comparison``'s runs folder share identical work
    (``OUT/<runs>_runs/_shared/``: content-keyed results a method stores there; no method's
    folder starts with ``_``)."""
    stem = comparison.runs or comparison.name
    return comparison.out / f"{stem}_runs" / SHARED


def cell_stamp(comparison: Comparison, method: Row, seed: int, thresholds: Any) -> dict[str, Any]:
    """What made the evaluation of cell ``(method, seed)``: its run (or agent, or expert: the
    row's :meth:`~safe_bc.compare.rows.Row.run_stamp`), the evaluation settings and tracks, the
    thresholds; its content key names the stored file
    (:func:`safe_bc.compare.eval_store.episodes_path`)."""
    settings = dataclasses.asdict(eval_config(comparison, method))
    settings.pop("workers")  # where episodes run changes nothing
    if settings["lockstep_forward"] == "rows":  # the one-env rows: stamps made before it hold
        settings.pop("lockstep_forward")
    if comparison.tracks != "heldout":
        settings["seeds"] = track_seeds(comparison)
    return _json(
        {
            "run": method.run_stamp(comparison, seed),
            "eval": settings,
            "thresholds": [float(x) for x in thresholds],
            "keep_steps": method.name in comparison.traces and seed == comparison.train_seeds[0],
        }
    )


def _stored(out: Path, stamp: dict[str, Any]) -> tuple[pd.DataFrame, dict] | None:
    """The stored evaluation (episodes, metadata) of ``stamp`` under ``out``, if any (its
    recorded stamp checked too)."""
    path = episodes_path(out, stamp)
    if not path.exists():
        return None
    frame, meta = read_table(path)
    return (frame, meta) if meta.get("stamp") == stamp else None


def _agent_ok(folder: Path, run: RunConfig, demos: Path, digest: str) -> bool:
    """Whether ``folder`` holds an agent trained by ``run`` on the demonstrations at ``demos``
    whose content digest is ``digest`` (an agent that records no digest, or another, was
    trained on another set: it is trained again)."""
    from safe_bc.bc import read_checkpoint_meta

    try:
        meta = read_checkpoint_meta(folder)
    except Exception:  # absent or torn: train again
        return False
    extra = meta.get("extra", {})
    return (
        extra.get("run") == _json(run.to_dict())
        and extra.get("demos") == str(demos)
        and extra.get("demos_digest") == digest
    )


def method_config(
    comparison: Comparison, method: FromStart, seed: int, improved: dict | None = None
) -> Any:
    """A method row's run config for training seed ``seed``
    (:meth:`~safe_bc.compare.rows.FromStart.config_for`)."""
    return method.config_for(comparison, seed, improved)


def method_identity(comparison: Comparison, method: FromStart, seed: int) -> Any:
    """What makes a method row's run for ``seed``
    (:meth:`~safe_bc.compare.rows.FromStart.identity`)."""
    return method.identity(comparison, seed)


def selfimprove_config(comparison: Comparison, method: FromStart, seed: int) -> Any:
    """A self-imitation row's run config for training seed ``seed`` (its ``seed``; the
    comparison task's values for the fields it leaves at ``None``)."""
    return method_config(comparison, method, seed).for_task(comparison.task)


selfimprove_identity = method_identity
"""A self-imitation row's identity (:func:`method_identity`)."""


def _copy_shared_rounds(c: Comparison, method: FromStart, seed: int, folder: Path) -> None:
    """Seed a new run of a method whose runs are rounds (``shares_rounds``) with the done
    rounds of another row of ``c`` whose run differs only in having fewer rounds (same method,
    start, seed and every other setting): a round depends on the settings, the seed and the
    rounds before it, never on how many follow, so those rounds are this run's first ones,
    bit for bit. The longest such run is copied (its start, start validation and done rounds,
    as hard links: a written round file is never changed, so the two runs share it on disk;
    ``identity.json`` is this run's own)."""
    import os
    import shutil

    from safe_bc.methods.layout import DONE, round_dir

    mine = method.identity(c, seed)
    best: tuple[int, Path] | None = None
    for other in method.siblings(c):
        theirs = other.identity(c, seed)
        if theirs["rounds"] >= mine["rounds"] or {**theirs, "rounds": 0} != {**mine, "rounds": 0}:
            continue
        source = _folder(c, other, seed) / other.spec.subfolder
        done = sum((source / round_dir(r) / DONE).is_file() for r in range(theirs["rounds"]))
        if done and (best is None or done > best[0]):
            best = (done, source)
    if best is None:
        return
    done, source = best
    tmp = folder.with_name(folder.name + ".copying")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    for name in ("start", "start_validation.json", *(round_dir(r) for r in range(done))):
        if (source / name).is_dir():
            shutil.copytree(source / name, tmp / name, copy_function=os.link)
        elif (source / name).is_file():
            os.link(source / name, tmp / name)
    tmp.rename(folder)


def _run_method(
    c: Comparison,
    method: FromStart,
    seed: int,
    data: Any,
    command: str | None,
    improved: dict | None = None,
) -> Any:
    """Run (or resume) a method row's run for ``seed`` from the start row's agent of that
    seed, in the start's env, on ``data`` (the start's demonstration set, loaded); a folder of
    another run (a changed setting or start) is redone. The method's
    :class:`~safe_bc.methods.Improved`."""
    from safe_bc.bc import load_checkpoint
    from safe_bc.methods import Start

    start = c.method(method.start)
    spec = method.spec
    agent = _folder(c, start, seed) / "agent"
    model, _ = load_checkpoint(agent)
    env = task_defaults(c.task, start.renderer or DEFAULT_RENDERER).env
    from safe_bc.distributed.rollouts import ChunkedRayRollouts

    begin = Start(
        model, run_config(c, start, seed), demos_of(c, method), env, agent, data,
        parallel=ChunkedRayRollouts, shared=shared_folder(c),
    )  # fmt: skip
    folder = _folder(c, method, seed) / spec.subfolder
    if spec.shares_rounds and not folder.exists():
        _copy_shared_rounds(c, method, seed, folder)
    config = method_config(c, method, seed, improved)

    def run() -> Any:
        return spec.run(config, begin, folder, metadata={"command": command})

    try:
        return run()
    except ValueError as e:  # a changed setting (or start) redoes the cell
        if "belongs to another" not in str(e):
            raise
        import shutil

        shutil.rmtree(folder)
        return run()


@dataclasses.dataclass
class _Runs:
    """The runner's side of :class:`~safe_bc.compare.rows.Runs`: the effects a row's policy
    and run are made of (checkpoints read, methods run, the expert and its handovers)."""

    comparison: Comparison
    sets: dict[Path, Any] = dataclasses.field(default_factory=dict)
    """Each demonstration set, loaded (a method run's training data)."""
    limits: dict[Path, Any] = dataclasses.field(default_factory=dict)
    """Each demonstration set's thresholds ``d_s``."""
    runs: dict | None = None
    """The method runs done so far, by ``(row, seed)`` (a ``budget_of`` row's source's)."""
    command: str | None = None

    def agent(self, row: Row, seed: int) -> Any:
        from safe_bc.bc import load_checkpoint

        return NetSource.from_model(*load_checkpoint(_folder(self.comparison, row, seed) / "agent"))

    def improved(self, row: FromStart, seed: int) -> Any:
        assert self.runs is not None
        return self.runs[row.name, seed]

    def run_method(self, row: FromStart, seed: int) -> Any:
        c = self.comparison
        return _run_method(c, row, seed, self.sets[demos_of(c, row)], self.command, self.runs)

    def expert(self, config: Any) -> Any:
        from safe_bc.rollout.collect import stored_expert_config

        own = stored_expert_config(self.comparison.demos) if config is None else config
        return ExpertSource(own)

    def masked(self, source: Any) -> Any:
        return MaskedSource(source)

    def handover(self, row: Handover, net: Any, seed: int) -> Any:
        """``net`` (a BC agent, or a method run's net without its own shield) with the scripted
        expert in the critical states of ``row``, by its evaluation thresholds."""
        from safe_bc.methods.common import shielded
        from safe_bc.rollout.collect import stored_expert_config
        from safe_bc.selection import CriticalZone

        c = self.comparison
        limits = tuple(float(x) for x in self.limits[demos_of(c, row)])
        expert, task = stored_expert_config(c.demos), task_defaults(c.task)
        if row.handover is not None:
            from safe_bc.rollout.handover import handover_source

            return handover_source(net, row.handover, expert, limits, task.safety_dims)
        zone = CriticalZone(limits, c.width, "any")
        return shielded(net, ExpertSource(expert), zone, task.env.env_id)


def _load_sets(
    comparison: Comparison, progress: bool
) -> tuple[dict[Path, Any], dict[Path, dict[str, Any]]]:
    """Every demonstration set the rows need (collected when missing), the comparison's
    first, and the record a table keeps of each (:func:`read_demonstrations`: read once for
    both): ``(sets, records)``; warns when a BC row's frames were drawn by another renderer."""
    from safe_bc.distributed.collect import ensure_demos

    sets: dict[Path, Any] = {}
    records: dict[Path, dict[str, Any]] = {}
    for path, collect in own_demos(comparison).items():
        ensure_demos(path, collect, progress=progress)
        sets[path], records[path] = read_demonstrations(path)
    for m in _trained_rows(comparison):  # a BC agent trains on frames drawn by its renderer
        path = demos_of(comparison, m)
        env = eval_config(comparison, m).env
        warning = check_frames_renderer(read_meta(path).renderer, env, path)
        if warning and progress:
            print(f"warning: {warning}")
    return sets, records


def _trained_rows(comparison: Comparison) -> list[Row]:
    """The rows that train BC agents of their own."""
    c = comparison
    return [m for m in c.methods if any(m.agent_run(c, s) is not None for s in c.seeds_of(m))]


def _train_agents(
    c: Comparison,
    sets: dict[Path, Any],
    records: dict[Path, dict[str, Any]],
    cells: list[tuple[Row, int]],
    progress: bool,
) -> None:
    """Train and store the BC agents of ``cells`` not on disk (fail fast on an impossible
    rule before any training)."""
    from safe_bc.bc.checkpoint import checkpoint_unit
    from safe_bc.distributed.train import train_many

    demos = sets[c.demos]
    digests = {path: record["digest"] for path, record in records.items()}
    runs = [(m, s, m.agent_run(c, s)) for m, s in cells]
    todo = [
        (m, s, run)
        for m, s, run in runs
        if run is not None
        and not _agent_ok(_folder(c, m, s) / "agent", run, demos_of(c, m), digests[demos_of(c, m)])
    ]
    for m, _, run in todo:
        select_for(sets[demos_of(c, m)], run.selection).sampler(
            run.bc.train.batch_size, np.random.default_rng(0)
        )
    if progress:
        print(f"compare {c.name}: {len(cells)} cells, training {len(todo)} agents")
    trained: list[Any] = [None] * len(todo)
    for path, data in sets.items():  # one training call per demonstration set
        idx = [i for i, (m, *_) in enumerate(todo) if demos_of(c, m) == path]
        if not idx:
            continue
        results = train_many(
            data, [todo[i][2] for i in idx], workers=max(c.workers, 1),
            action_bounds=dataset_action_bounds(path), progress=progress,
        )  # fmt: skip
        for i, r in zip(idx, results, strict=True):
            trained[i] = r
    for (m, s, run), (result, selection) in zip(todo, trained, strict=True):
        env_id = task_defaults(c.task, m.renderer or DEFAULT_RENDERER).env.env_id
        train_row = {
            "final_loss": result.final_loss,
            "samples_per_s": result.samples_per_s,
            "n_critical": selection.n_critical,
            "n_train_rows": selection.n_train_rows,
            "critical_sample_share": selection.critical_sample_share,
        }
        agent_meta = _json(
            run_metadata(
                demos=str(demos_of(c, m)), demos_digest=digests[demos_of(c, m)], env_id=env_id,
                run=run.to_dict(), train=result.summary(), train_row=train_row,
            )
        )  # fmt: skip
        with checkpoint_unit(_folder(c, m, s) / "agent") as unit:
            result.save(unit, extra=agent_meta)
            save_selection(unit, demos, selection, agent_meta)
            save_curve(unit, result, agent_meta)


def _improve_cell(
    c: Comparison,
    m: Row,
    s: int,
    sets: dict[Path, Any],
    command: str | None,
    improved: dict | None = None,
) -> tuple[pd.DataFrame, dict[str, Any], Any] | None:
    """Run (or resume) the method run of cell ``(m, s)``: its learning curve, the metadata of
    the machine that ran it and the method's :class:`~safe_bc.methods.Improved`; ``None`` for
    the other rows. ``improved``: the runs done so far (a ``budget_of`` row's source's)."""
    runs = _Runs(c, sets, runs=improved, command=command)
    done = m.method_run(runs, s)
    if done is None:
        return None
    history = done.history.assign(method=m.name, train_seed=s)
    if done.meta is not None:
        return history, done.meta, done
    where = _folder(c, m, s) / m.spec.subfolder / "run.json"  # type: ignore[attr-defined]  # the machine that last ran it
    if done.fresh or not where.is_file():
        write_text_atomic(where, json.dumps(_json(run_metadata())))
    return history, json.loads(where.read_text()), done


def run_cell(
    comparison: Comparison, cell: str, *, workers: int | None = None, progress: bool = True
) -> Path:
    """Train (a BC row) or improve (a method row, its start trained first when missing) the
    one cell ``"METHOD:SEED"``: no evaluation, no tables. Cells are independent, so a
    comparison's cells can run in parallel processes or on other machines sharing ``out``; a
    later :func:`run_comparison` reuses them (each cell's folder records the machine that ran
    it). ``workers`` overrides the rollout actors of a method row whose config has ``workers``
    (self-imitation, queries; 0: in this process; results do not depend on it). Returns the
    cell's folder."""
    c = comparison
    name, sep, seed_text = cell.rpartition(":")
    if not sep or not seed_text.isdigit():
        raise ValueError(f"a cell reads METHOD:SEED (e.g. imitation:0), got {cell!r}")
    names = [x.name for x in c.methods]
    if name not in names:
        raise ValueError(f"{c.name} has no method {name!r}; its methods: {', '.join(names)}")
    m, s = c.method(name), int(seed_text)
    if s not in c.seeds_of(m):
        raise ValueError(f"{name} has training seeds {list(c.seeds_of(m))}, not {s}")
    if workers is not None and m.with_workers(workers) != m:
        m = m.with_workers(workers)
        c = dataclasses.replace(c, methods=tuple(m if x.name == name else x for x in c.methods))
    sets, records = _load_sets(c, progress)
    _train_agents(c, sets, records, list(m.needs(c, s)), progress)
    command, improved = run_metadata().get("command"), {}
    of = m.budget_of
    if of:  # the run that sets the budget first (resumed when done)
        improved[of, s] = _improve_cell(c, c.method(of), s, sets, command)[2]  # type: ignore[index]
    _improve_cell(c, m, s, sets, command, improved)
    return _folder(c, m, s)


@dataclasses.dataclass(frozen=True)
class Cell:
    """One evaluated (row, training seed) of a comparison's plan."""

    row: Row
    """The row."""
    seed: int
    """The training seed (an expert row's one seed)."""
    stamp: dict[str, Any]
    """What made its evaluation (:func:`cell_stamp`): its stored file's key."""


def plan_evaluations(comparison: Comparison, limits: dict[Path, Any]) -> dict[str, Cell]:
    """Every cell's evaluation, by its policy key in the episode tables (``"expert"`` for the
    default expert, else ``"<row> seed=<k>"``), in spec order; ``limits``: each demonstration
    set's thresholds ``d_s`` (the evaluation thresholds of the rows behind it). Pure."""
    c = comparison
    plan: dict[str, Cell] = {}
    for m, s in _cells(c):
        plan[m.policy_key(s)] = Cell(m, s, cell_stamp(c, m, s, limits[demos_of(c, m)]))
    return plan


def run_comparison(
    comparison: Comparison, *, progress: bool = True, command: str | None = None
) -> pd.DataFrame:
    """Train, improve and evaluate what is missing, then write every output (module doc).

    Returns:
        The table (:func:`safe_bc.compare.spec.build_table`).
    """
    started = time.perf_counter()
    c = comparison
    sets, records = _load_sets(c, progress)
    meta = run_metadata(
        config=_json(c.to_dict()),
        train_seeds=list(c.train_seeds),
        eval_seed=c.eval_seed,
        inputs={"demos": list(records.values())},
    )
    if command is not None:
        meta["command"] = command
    c.out.mkdir(parents=True, exist_ok=True)
    eps = selection_eps(c)
    save_selection(
        c.out / f"{c.name}_selection", sets[c.demos],
        select_for(sets[c.demos], SelectionConfig(eps=eps, alpha=0.0)), meta,
    )  # fmt: skip
    limits = {  # each set's d_s: the evaluation thresholds of the rows behind it
        path: select_for(d, SelectionConfig(eps=eps, alpha=0.0)).thresholds
        for path, d in sets.items()
    }
    # 1. BC agents not on disk; 2. method runs (each resumes itself), one after the other
    _train_agents(c, sets, records, _cells(c), progress)
    histories, run_metas, improved = [], [], {}
    for m, s in _cells(c):
        ran = _improve_cell(c, m, s, sets, meta.get("command"), improved)
        if ran is not None:
            history, run_meta, improved[m.name, s] = ran
            histories.append(history)
            run_metas.append(run_meta)
    # 3. the evaluations not stored, in one call per (env, thresholds); 4. the outputs
    plan = plan_evaluations(c, limits)
    stored, eval_metas = _evaluate(c, plan, _Runs(c, sets, limits, improved), meta, progress)
    meta["seconds"] = round(time.perf_counter() - started, 1)
    meta["inputs"] = {**meta["inputs"], "runs": run_digests(c, plan)}
    meta["demo_safety_mean"] = float(combined(sets[c.demos].safety[sets[c.demos].scored]).mean())
    meta["limit_distances"] = limit_distances(sets[c.demos])
    meta["run_machines"] = machines(run_metas)
    meta["eval_machines"] = machines(eval_metas)
    table = _report(c, plan, stored, meta, histories)
    run_report(c, meta["command"])
    return table


def _evaluate(
    c: Comparison,
    plan: dict[str, Cell],
    runs: _Runs,
    meta: dict[str, Any],
    progress: bool,
) -> tuple[dict[str, pd.DataFrame], list[dict[str, Any]]]:
    """Every planned cell's episodes (by policy key), read from its stored evaluation or
    evaluated now (all missing ones in one call per env and thresholds, each then stored under
    its key), and the metadata of each evaluation; each policy made by its row
    (:meth:`~safe_bc.compare.rows.Row.policy`) through ``runs``."""
    from safe_bc.distributed.evaluate import LOCKSTEP_ENVS, evaluate_policies

    stored: dict[str, pd.DataFrame] = {}
    eval_metas: list[dict[str, Any]] = []
    groups: dict[tuple[str, Path], list[str]] = {}  # the missing ones, per (env, thresholds)
    for key, cell in plan.items():
        have = _stored(c.out, cell.stamp)
        if have is not None:  # the policy named as this comparison names it
            stored[key] = have[0].assign(policy=key)
            eval_metas.append(have[1])
        else:
            m = cell.row
            groups.setdefault((m.renderer or DEFAULT_RENDERER, demos_of(c, m)), []).append(key)
    if progress:
        missing = sum(len(keys) for keys in groups.values())
        print(f"compare {c.name}: evaluating {missing} of {len(plan)} policies")
    for keys in groups.values():
        m = plan[keys[0]].row
        episodes, steps = evaluate_policies(
            {k: plan[k].row.policy(runs, plan[k].seed) for k in keys}, eval_config(c, m),
            thresholds=runs.limits[demos_of(c, m)], progress=progress,
            envs_per_worker=LOCKSTEP_ENVS, seeds=track_seeds(c),
        )  # fmt: skip
        for key in keys:
            stamp = plan[key].stamp
            cell_meta = {**meta, "stamp": stamp}
            ep = episodes[episodes["policy"] == key].reset_index(drop=True)
            if stamp["keep_steps"]:
                st = steps[steps["policy"] == key].reset_index(drop=True)
                write_table_atomic(steps_path(c.out, stamp), st, cell_meta)
            write_table_atomic(episodes_path(c.out, stamp), ep, cell_meta)
            stored[key] = ep
            eval_metas.append(cell_meta)
    return stored, eval_metas


def episodes_table(plan: dict[str, Cell], stored: dict[str, pd.DataFrame]) -> pd.DataFrame:
    """The comparison's episodes: each planned cell's stored episodes (by policy key) with its
    row's labels and training seed, in plan order. Pure."""
    parts = []
    for key, cell in plan.items():
        labels = {**cell.row.labels, "train_seed": cell.seed}
        ep = stored[key]
        parts.append(
            pd.DataFrame({"policy": ep["policy"], **labels}).join(ep.drop(columns="policy"))
        )
    return pd.concat(parts, ignore_index=True)


def _report(
    c: Comparison,
    plan: dict[str, Cell],
    stored: dict[str, pd.DataFrame],
    meta: dict[str, Any],
    histories: list[pd.DataFrame],
) -> pd.DataFrame:
    """The episode, trace, training and history tables (in spec order), then the table, its
    Markdown and figures (:func:`write_outputs`)."""
    from safe_bc.bc import read_checkpoint_meta

    traces, train_rows = [], []
    for key, cell in plan.items():
        m, s = cell.row, cell.seed
        labels = {**m.labels, "train_seed": s}
        if cell.stamp["keep_steps"]:
            st = read_table(steps_path(c.out, cell.stamp))[0]
            traces.append(st.assign(policy=key))
        if m.agent_run(c, s) is not None:  # its own agent's training row
            extra = read_checkpoint_meta(_folder(c, m, s) / "agent")["extra"]
            train_rows.append({**labels, **extra["train_row"]})
    episodes = episodes_table(plan, stored)
    steps = pd.concat(traces, ignore_index=True) if traces else pd.DataFrame()
    train_df = pd.DataFrame(train_rows)
    write_table_atomic(c.out / f"{c.name}_episodes.parquet", episodes, meta)
    write_table_atomic(c.out / f"{c.name}_traces.parquet", steps, meta)
    write_table_atomic(c.out / f"{c.name}_training.parquet", train_df, meta)
    history = pd.concat(histories, ignore_index=True) if histories else None
    if history is not None:
        write_table_atomic(c.out / f"{c.name}_history.parquet", history, meta)
    return write_outputs(c, episodes, steps, train_df, meta, history)


def limit_distances(demos: Any) -> dict[str, float]:
    """Per safety dimension, the distance at the limit ``d_s``: the demonstrations' closest
    scored approach (``d_s`` is their largest cost, and a cost falls as the distance grows)."""
    scored = demos.safety[demos.scored]
    return {d: float(scored[:, j].min()) for j, d in enumerate(demos.safety_dims)}


def write_outputs(
    comparison: Comparison,
    episodes: pd.DataFrame,
    traces: pd.DataFrame,
    train_df: pd.DataFrame,
    meta: dict[str, Any],
    history: pd.DataFrame | None = None,
) -> pd.DataFrame:
    """The table, its Markdown and the figures from per-episode results (and the
    improvement rows' ``history``)."""
    c = comparison
    table = build_table(c, episodes, train_df, history)
    write_table_atomic(c.out / f"{c.name}.parquet", table, meta)
    write_text_atomic(c.out / f"{c.name}.md", render_markdown(c, table, meta, episodes))
    from safe_bc.plots import plot_alpha_sweep, plot_learning_curves, plot_traces

    task = task_defaults(c.task)
    for figure, file in c.figures:
        if figure == "alpha_sweep":
            sweep = table[table["mode"].isin(["mix", EXPERT])]  # the baselines have no alpha
            plot_alpha_sweep(
                sweep, c.out / file, paper=PAPER_TABLE1 if c.paper else None,
                units=task.safety_units,
            )  # fmt: skip
        elif figure == "traces" and len(traces):
            pairs = episodes[["policy", "method"]].drop_duplicates().values
            plot_traces(
                traces, {p: {"method": m} for p, m in pairs}, c.out / file,
                limits=meta.get("limit_distances"),
                units=dict(zip(task.safety_dims, task.safety_units, strict=False)),
            )  # fmt: skip
        elif figure == "learning_curves" and history is not None and len(history):
            means = episodes.groupby("method")["reward"].mean()
            named = {r for m in c.methods for r in m.curve_refs()}  # the expert's, the starts'
            refs = {  # their held-out mean reward, in table order
                c.label_of(m.name): float(means[m.name])
                for m in c.methods
                if m.name in named and m.name in means
            }
            labels = {m.name: m.shown for m in c.methods}
            plot_learning_curves(history, refs, c.out / file, labels=labels)
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
    history_path = c.out / f"{c.name}_history.parquet"
    history = read_table(history_path)[0] if history_path.exists() else None
    meta = {**meta, "rendered": run_metadata()}
    if "limit_distances" not in meta:
        found = stored_limit_distances(c)
        meta.update({"limit_distances": found} if found is not None else {})
    table = write_outputs(c, episodes, traces, train_df, meta, history)
    run_report(c, meta["rendered"]["command"])
    return table


def run_report(comparison: Comparison, command: str | None = None) -> list[Path]:
    """The comparison's report step (:attr:`~safe_bc.compare.spec.Comparison.report`) on the
    tables it wrote (``OUT/<name>.parquet`` and those the step reads, each read back with its
    provenance): a text step's text written to ``OUT/<report.file>``, or every file of a
    :class:`~safe_bc.compare.spec.ReportFiles` (:func:`write_report_files`). ``command``: the
    command the outputs record (``None``: this process's). Returns the files written (none
    without a report step).

    Raises:
        FileNotFoundError: a table has not been written (run the comparison first).
        TypeError: the step returned other than its kind returns.
    """
    c = comparison
    if c.report is None:
        return []
    paths = {"": c.out / f"{c.name}.parquet"}
    paths |= {t: c.out / f"{c.name}_{t}.parquet" for t in c.report.reads}
    for path in paths.values():
        if not path.is_file():
            raise FileNotFoundError(f"{path} is missing: run the comparison {c.name!r} first")
    (table, meta, source), *reads = (Read(*read_table(p), p) for p in paths.values())
    module, _, function = c.report.step.partition(":")
    step = getattr(importlib.import_module(module), function)
    command = command_line() if command is None else command
    made = step(table, meta, source, command, **dict(zip(c.report.reads, reads, strict=True)))
    kind = str if c.report.file else ReportFiles
    if not isinstance(made, kind):
        raise TypeError(
            f"report step {c.report.step} returned a {type(made).__name__}, not a {kind.__name__}"
        )
    if isinstance(made, str):
        path = c.out / c.report.file
        write_text_atomic(path, made)
        return [path]
    return write_report_files(c, made, command, list(paths.values()))


def write_report_files(
    comparison: Comparison, files: ReportFiles, command: str, read: list[Path]
) -> list[Path]:
    """Every file of ``files`` into the comparison's ``out``, each atomically: the tables with
    their metadata, this run's provenance, ``command`` and the digests of the tables ``read``
    (``inputs.tables``), the texts, the figures (each drawn by its plot function). Returns the
    files written.

    Raises:
        ValueError: a name is no file name, repeats, or is one of the comparison's own files.
    """
    c = comparison
    check_report_files(c, files)
    meta = run_metadata(**files.meta)
    meta["command"] = command
    meta["inputs"] = {
        **files.meta.get("inputs", {}),
        "tables": {str(p): file_digest(p) for p in read},
    }
    written = []
    for name, frame in files.tables.items():
        written.append(c.out / f"{name}.parquet")
        write_table_atomic(written[-1], frame, meta)
    for name, text in files.texts.items():
        written.append(c.out / name)
        write_text_atomic(written[-1], text)
    for name, plot in files.figures.items():
        module, _, function = plot.function.partition(":")
        written.append(c.out / name)
        getattr(importlib.import_module(module), function)(**plot.args, path=written[-1])
    return written


def stored_limit_distances(c: Comparison) -> dict[str, float] | None:
    """:func:`limit_distances` of the comparison's demonstrations for a run whose tables
    predate recording them: read from ``c.demos`` when it is there and its ``d_s`` are the
    ones the run's selection table recorded (the same set); else ``None``."""
    selection = c.out / f"{c.name}_selection" / "selection.parquet"
    if not (selection.exists() and Path(c.demos).exists()):
        return None
    from safe_bc.data.store import load_demonstrations, read_table_metadata

    recorded = read_table_metadata(selection).get("thresholds")
    demos = load_demonstrations(c.demos)
    found = select_for(demos, SelectionConfig(eps=selection_eps(c), alpha=0.0)).thresholds
    if recorded is None or not np.allclose(found, recorded, rtol=0, atol=1e-6):
        return None
    return limit_distances(demos)
