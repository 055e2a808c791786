"""Critical-zone queries and deferral measured without Ray: plain BC, full DAgger at the same
number of queries, critical-zone queries and deferral, on selection tracks then fresh tracks
(CarRacing) or selection and fresh patients (``--task rehab``: the guideline clinician is the
expert).

Run: ``SDL_VIDEODRIVER=dummy python -m safe_bc.queries.measure --out DIR --processes 16``
(``--task rehab --out DIR`` for the clinic).
Work runs in a ``multiprocessing`` pool (fork, one torch thread per process); the training
seeds' pipelines are threads of this process that hand every training and episode to it.

1. Demonstrations: ``--demos`` (default: the task's, ``data/demos`` or ``data/rehab_demos``),
   collected there (the task's default collection) when missing.
2. Per training seed k: plain BC (``--alpha``, default :data:`ALPHA`: the alpha of the task's
   committed improvement starts), then ``critical`` queries from it, then ``full``
   (DAgger) with a per-round budget of the critical run's mean queries per round. The query
   rounds run while the rest of the pool evaluates plain BC, its deferral and the expert.
3. Deferral of plain BC on the *selection* tracks (held-out block ``SELECTION_BLOCK``) for each
   width of ``--widths``; the chosen width is the smallest with no episode beyond ``d_s``.
4. Deferral over the critical-zone queries' agent (``critical+defer``): its width chosen the
   same way on the selection tracks.
5. ``bc_safe``: OSRL's BC-Safe (``SelectionConfig(mode="bc_safe")``, alpha 0), a peer baseline
   that asks the expert nothing; added after Table 1 on raster frames drew 0 of 110 episodes
   beyond ``d_s`` for it, so that the draw is tested on tracks that did not suggest it.
6. Every method (and both deferrals at their chosen widths, and the expert) on the *fresh*
   tracks (block ``FRESH_BLOCK``), :data:`TRACKS` per seed by default (50 tracks, 200
   patients).

An episode is *beyond d_s* when a scored step is (``violation_steps``; CarRacing) or when a
session's outcome is, the last one included (``violating_sessions``; rehab, whose
``violation_steps`` scores the state before each session and misses the last outcome):
:data:`CROSSING`.

Resumable per (method, seed): every finished unit is a file (checkpoints, round folders,
``episodes/<block>/<method>-<seed>.parquet``); a rerun does the rest. Outputs:
``summary.parquet`` and ``summary.md`` (per block and method: episodes beyond ``d_s`` and
their one-sided 95% Clopper-Pearson bound, reward and its paired crossed-bootstrap
difference to the expert, queries or deferred steps per episode) and ``widths.parquet``.
"""

from __future__ import annotations

import math
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

SELECTION_BLOCK = 11
"""Held-out seed block of the selection tracks (no other table uses it: Table 1 uses 0, the
study 1 and 2, the improvement runs 7)."""
FRESH_BLOCK = 12
"""Held-out seed block of the fresh tracks."""
METHODS = ("bc", "full", "critical")
CRITICAL_DEFER = "critical+defer"
"""Deferral composed with the critical-zone queries' agent (its own width)."""
BC_SAFE = "bc_safe"
"""OSRL's BC-Safe at the task's eps: no queries, no deferral."""
TRACKS = {"carracing": 50, "rehab": 200}
"""Tracks (patients) per block and training seed: the issue's design (3 seeds x 50 tracks; the
clinic x 200 patients)."""
ALPHA = {"carracing": 0.1, "rehab": 0.5}
"""Plain BC's alpha: that of the task's committed improvement starts
(``tune_jobs/compare/improve_carracing.py``, ``improve_rehab.py``)."""
WIDTHS = {"carracing": (1.0, 2.0, 4.0, 8.0), "rehab": (0.025, 0.05, 0.1, 0.2)}
"""Deferral widths tried on the selection tracks, in cost units: CarRacing px (half, one,
two and four times its eps of 2 px); rehab cost units (the same multiples of its eps, 0.05)."""
UNITS = {"carracing": "tracks", "rehab": "patients"}
"""What a held-out episode is called."""
CROSSING = {"carracing": "violation_steps", "rehab": "violating_sessions"}
"""The per-episode count whose being above 0 makes an episode *beyond d_s*."""

_STATE: dict[str, Any] = {}


def _init_worker() -> None:
    import torch

    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    torch.set_num_threads(1)


def _collect_one(args: tuple[Any, int]) -> Any:
    from safe_bc.collection import EpisodeMaker

    cfg, i = args
    maker = EpisodeMaker(cfg)
    try:
        return maker.make(i)
    finally:
        maker.close()


def _train(job: Any) -> Any:
    from safe_bc.rounds import train_local

    return train_local(job)


def _rollout(args: tuple[Any, tuple[int, ...]]) -> Any:
    from safe_bc.queries.rollout import query_tracks

    return query_tracks(*args)


def _episode(args: tuple[Any, Any, int, np.ndarray, float, int | None]) -> dict[str, Any]:
    """One evaluated episode in a worker (its env kept between calls)."""
    from safe_bc.envs import make_env
    from safe_bc.evaluation import evaluate_episode

    env_config, source, seed, limits, eps, max_steps = args
    if _STATE.get("env_config") != env_config:
        _STATE["env"], _STATE["env_config"] = make_env(env_config), env_config
    policy = source.build()
    metrics, _ = evaluate_episode(
        _STATE["env"], policy, seed, thresholds=limits, eps=eps, max_steps=max_steps
    )
    return {"env_seed": seed, **metrics}


def ensure_demos(root: Path, pool: Any, task: str = "carracing") -> None:
    """``task``'s default demonstrations at ``root`` (collected in the pool when missing)."""
    from safe_bc.collection import CollectConfig, config_dict, env_facts
    from safe_bc.data.store import DatasetMeta, init_dataset, write_episode
    from safe_bc.provenance import provenance
    from safe_bc.tasks import frames_renderer, task_defaults

    if (root / "dataset.json").is_file():
        return
    cfg = CollectConfig.for_task(task_defaults(task))
    shape, dims, bounds = env_facts(cfg)
    meta = init_dataset(
        root,
        DatasetMeta(
            env_id=cfg.env.env_id,
            obs_encoding=cfg.encoding,
            obs_shape=shape,
            safety_dims=dims,
            seed=cfg.seed,
            max_steps=cfg.max_steps,
            expert=config_dict(cfg.expert),
            perturbation=config_dict(cfg.perturbation),
            provenance=provenance(),
            action_bounds=bounds,
            renderer=frames_renderer(cfg.env),
        ),
    )
    for ep in pool.map(_collect_one, [(cfg, i) for i in range(cfg.episodes)]):
        write_episode(root, ep, meta)


@dataclass(frozen=True)
class MeasureConfig:
    """The measurement's settings (``python -m safe_bc.queries.measure --help``)."""

    out: Path
    """Output folder (resumable: a rerun does what is missing)."""
    task: Literal["carracing", "rehab"] = "carracing"
    """The testbed: the car (the scripted expert) or the clinic (the guideline clinician)."""
    processes: int = 16
    """Worker processes (one torch thread each)."""
    demos: Path | None = None
    """Demonstrations (None: the task's, ``data/demos`` or ``data/rehab_demos``; its default
    collection is made there when missing)."""
    seeds: tuple[int, ...] = (0, 1, 2)
    """Training seeds."""
    tracks: int | None = None
    """Tracks (patients) per block (selection, fresh) and training seed (None:
    :data:`TRACKS`, 50 tracks or 200 patients)."""
    alpha: float | None = None
    """Plain BC's alpha (None: :data:`ALPHA`, the task's committed improvement starts')."""
    batches: int = 2000
    """Training batches of every BC fit."""
    rounds: int = 2
    """Query rounds (critical and full)."""
    episodes_per_round: int = 16
    """Rollouts per query round."""
    widths: tuple[float, ...] | None = None
    """Deferral widths (cost units) tried on the selection tracks, smallest first (None:
    :data:`WIDTHS`)."""
    max_steps: int | None = None
    """Episode step cap (None: the env's time limit)."""

    def resolved(self) -> MeasureConfig:
        """This config with the task's values for every field left at None."""
        from safe_bc.tasks import task_defaults

        return replace(
            self,
            demos=Path(task_defaults(self.task).demos) if self.demos is None else self.demos,
            tracks=TRACKS[self.task] if self.tracks is None else self.tracks,
            alpha=ALPHA[self.task] if self.alpha is None else self.alpha,
            widths=WIDTHS[self.task] if self.widths is None else self.widths,
        )


def main(argv: list[str] | None = None) -> int:
    import tyro

    a = tyro.cli(MeasureConfig, args=argv, description=__doc__.splitlines()[0]).resolved()
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    import multiprocessing

    t0 = time.perf_counter()
    with multiprocessing.get_context("fork").Pool(a.processes, _init_worker) as pool:
        ensure_demos(a.demos, pool, a.task)
        summary = run(a, pool)
    print(summary)
    print(f"done in {time.perf_counter() - t0:.0f} s")
    return 0


def run(a: MeasureConfig, pool: Any) -> str:
    import pandas as pd

    from safe_bc.bc.config import BCConfig, TrainConfig
    from safe_bc.data.store import load_demonstrations
    from safe_bc.evaluation import ExpertSource
    from safe_bc.experiment import select_for
    from safe_bc.queries.config import QueryConfig
    from safe_bc.queries.defer import DeferralSource
    from safe_bc.queries.logic import smallest_safe_width
    from safe_bc.queries.run import run_queries
    from safe_bc.queries.stage import expert_for
    from safe_bc.rounds import TrainJob, net_model, policy_source
    from safe_bc.run_config import RunConfig
    from safe_bc.selection import SelectionConfig
    from safe_bc.tasks import dataset_action_bounds, task_defaults

    a = a.resolved()
    assert a.demos is not None and a.tracks is not None and a.widths is not None
    assert a.alpha is not None
    out = a.out
    out.mkdir(parents=True, exist_ok=True)
    demos = load_demonstrations(a.demos)
    task = task_defaults(a.task)
    crossing = CROSSING[a.task]
    env, expert = task.env, expert_for(a.demos, task.env.env_id)
    bounds = dataset_action_bounds(a.demos)
    base_sel = SelectionConfig(eps=task.eps, alpha=a.alpha)
    limits = select_for(demos, base_sel).thresholds

    def run_config(seed: int) -> RunConfig:
        return RunConfig(base_sel, BCConfig(train=TrainConfig(batches=a.batches, seed=seed)))

    def rollouts(job: Any, seeds: Any) -> list[Any]:
        return [e for part in pool.map(_rollout, [(job, (s,)) for s in seeds]) for e in part]

    def train(job: Any) -> Any:
        return pool.apply(_train, (job,))

    def train_bc(seed: int, name: str = "bc") -> Any:
        """Plain BC (or BC-Safe) for one seed (its checkpoint, reused when present)."""
        from safe_bc.bc.checkpoint import checkpoint_unit, save_checkpoint

        cfg = run_config(seed)
        if name == BC_SAFE:
            cfg = replace(cfg, selection=SelectionConfig(eps=task.eps, mode="bc_safe"))
        bc_dir = out / name / f"seed{seed}"
        if not (bc_dir / "config.json").is_file():
            sel = select_for(demos, cfg.selection)
            src = train(TrainJob(demos, sel, cfg, bounds))
            with checkpoint_unit(bc_dir) as unit:
                save_checkpoint(unit, net_model(src), cfg.bc)
        return policy_source(bc_dir)

    def pipeline(seed: int) -> dict[str, Any]:
        """Critical, then full (at the critical run's queries) from one seed's plain BC."""
        cfg = run_config(seed)
        start = net_model(bcs[seed])
        common = {
            "rounds": a.rounds,
            "episodes_per_round": a.episodes_per_round,
            "max_steps": a.max_steps,
            "seed": seed,
        }
        kw = {"rollouts": rollouts, "train": train, "action_bounds": bounds}
        crit = run_queries(
            start,
            cfg,
            demos,
            a.demos,
            env,
            expert,
            out / "critical" / f"seed{seed}",
            QueryConfig(mode="critical", **common),
            **kw,
        )
        budget = max(1, math.ceil(crit.total_queries / a.rounds))
        full = run_queries(
            start,
            cfg,
            demos,
            a.demos,
            env,
            expert,
            out / "full" / f"seed{seed}",
            QueryConfig(mode="full", query_budget=budget, **common),
            **kw,
        )
        return {
            "critical": (policy_source(crit.policy), crit.total_queries / crit.total_episodes),
            "full": (policy_source(full.policy), full.total_queries / full.total_episodes),
        }

    with ThreadPoolExecutor(len(a.seeds)) as threads:
        bcs = dict(zip(a.seeds, threads.map(train_bc, a.seeds), strict=True))
    # the query rounds (a few processes) run while the rest of the pool evaluates plain BC,
    # its deferral and the expert; the query agents are evaluated once they are trained
    threads = ThreadPoolExecutor(len(a.seeds))
    queried = {s: threads.submit(pipeline, s) for s in a.seeds}
    agents: dict[int, dict[str, Any]] = {s: {"bc": (bcs[s], float("nan"))} for s in a.seeds}

    def evaluate(block: int, name: str, seed: int, source: Any) -> pd.DataFrame:
        """One (block, method, seed) unit: its episodes (resumable file)."""
        from safe_bc.data.store import read_table, write_table_atomic
        from safe_bc.provenance import run_metadata
        from safe_bc.seeds import heldout_seeds

        path = out / "episodes" / f"block{block}" / f"{name}-{seed}.parquet"
        if path.is_file():
            return read_table(path)[0]
        tracks = heldout_seeds(block, a.tracks)
        rows = pool.map(_episode, [(env, source, t, limits, task.eps, a.max_steps) for t in tracks])
        df = pd.DataFrame(rows).assign(method=name, train_seed=seed, block=block)
        write_table_atomic(path, df, run_metadata(method=name, train_seed=seed, block=block))
        return df

    def defer_source(seed: int, w: float, agent: Any = None) -> Any:
        return DeferralSource(
            bcs[seed] if agent is None else agent, expert, tuple(limits), w, base_sel.combine
        )

    def choose_width(prefix: str, agent_of: Any) -> tuple[float, dict[float, int]]:
        """Widths on the selection tracks, smallest first, until one reaches zero crossings:
        the chosen width (the largest tried when none does) and the crossings per width."""
        crossings: dict[float, int] = {}
        for w in sorted(a.widths):
            eps = [
                evaluate(SELECTION_BLOCK, f"{prefix}-{w:g}", s, defer_source(s, w, agent_of(s)))
                for s in a.seeds
            ]
            crossings[w] = int(sum((e[crossing] > 0).sum() for e in eps))
            if crossings[w] == 0:
                break
        chosen = smallest_safe_width(crossings)
        return (max(a.widths) if chosen is None else chosen), crossings

    width, crossings = choose_width("defer", lambda s: None)

    frames = []
    for block in (SELECTION_BLOCK, FRESH_BLOCK):
        frames.append(evaluate(block, "expert", -1, ExpertSource(expert)))
        for s in a.seeds:
            frames.append(evaluate(block, "bc", s, bcs[s]))
            reuse = block == SELECTION_BLOCK and width in crossings  # measured while choosing
            name = f"defer-{width:g}" if reuse else "defer"
            frames.append(evaluate(block, name, s, defer_source(s, width)).assign(method="defer"))
    safe = {s: train_bc(s, BC_SAFE) for s in a.seeds}
    for block in (SELECTION_BLOCK, FRESH_BLOCK):
        for s in a.seeds:
            frames.append(evaluate(block, BC_SAFE, s, safe[s]))
    for s in a.seeds:
        agents[s].update(queried[s].result())
    threads.shutdown()
    for block in (SELECTION_BLOCK, FRESH_BLOCK):
        for s in a.seeds:
            for name in ("full", "critical"):
                frames.append(evaluate(block, name, s, agents[s][name][0]))
    # deferral composed with the critical-zone queries' agent: its own width, chosen the same way
    width_c, crossings_c = choose_width(CRITICAL_DEFER, lambda s: agents[s]["critical"][0])
    for block in (SELECTION_BLOCK, FRESH_BLOCK):
        for s in a.seeds:
            reuse = block == SELECTION_BLOCK and width_c in crossings_c
            name = f"{CRITICAL_DEFER}-{width_c:g}" if reuse else CRITICAL_DEFER
            source = defer_source(s, width_c, agents[s]["critical"][0])
            frames.append(evaluate(block, name, s, source).assign(method=CRITICAL_DEFER))
    pd.DataFrame(
        [
            {"agent": agent, "width": w, "episodes_beyond": k, "episodes": len(a.seeds) * a.tracks}
            for agent, tried in (("bc", crossings), ("critical", crossings_c))
            for w, k in tried.items()
        ]
    ).to_parquet(out / "widths.parquet")
    episodes = pd.concat(frames, ignore_index=True)
    queries = {m: float(np.mean([agents[s][m][1] for s in a.seeds])) for m in METHODS}
    queries[CRITICAL_DEFER] = queries["critical"]  # its agent's training queries
    queries[BC_SAFE] = 0.0
    table = summarize(episodes, queries, {"defer": width, CRITICAL_DEFER: width_c}, crossing)
    from safe_bc.data.store import write_table_atomic
    from safe_bc.provenance import run_metadata

    meta = run_metadata(
        task=a.task,
        crossing=crossing,
        seeds=a.seeds,
        tracks=a.tracks,
        alpha=a.alpha,
        batches=a.batches,
        rounds=a.rounds,
        episodes_per_round=a.episodes_per_round,
        width=width,
        crossings={str(k): v for k, v in crossings.items()},
        critical_defer_width=width_c,
        critical_defer_crossings={str(k): v for k, v in crossings_c.items()},
        limits=[float(x) for x in limits],
        demos=str(a.demos),
    )
    write_table_atomic(out / "summary.parquet", table, meta)

    def how(w: float, tried: dict[float, int]) -> str:
        if tried.get(w) == 0:
            return f"the smallest of {sorted(a.widths)} with no selection episode beyond d_s"
        return f"none of {sorted(a.widths)} reached zero selection crossings: the largest"

    text = (
        f"# Critical-zone queries and deferral (issue 35, {a.task})\n\nTraining seeds "
        f"{a.seeds}, {a.tracks} {UNITS[a.task]} per seed and block (selection: held-out block "
        f"{SELECTION_BLOCK}; "
        f"fresh: {FRESH_BLOCK}). Deferral width w = {width:g} ({how(width, crossings)}; "
        f"crossings per width {crossings}). Deferral over the critical-zone queries' agent "
        f"({CRITICAL_DEFER}): w = {width_c:g}, chosen the same way ({how(width_c, crossings_c)}; "
        f"crossings per width {crossings_c}); its queries are its agent's training "
        f"queries. {BC_SAFE}: OSRL's BC-Safe (alpha 0), no queries. An episode is beyond "
        f"d_s when its `{crossing}` is above 0.\n\n"
        + table.to_markdown(index=False, floatfmt=".3g")
        + f"\n\nProvenance: `{meta['command']}`\n"
    )
    (out / "summary.md").write_text(text)
    return text


def summarize(
    episodes: Any,
    queries: dict[str, float],
    widths: dict[str, float],
    crossing: str = "violation_steps",
) -> Any:
    """Per (block, method): episodes beyond d_s (``crossing`` above 0), their 95% upper bound,
    reward and its paired difference to the expert (crossed bootstrap), queries / deferred
    steps per episode."""
    import pandas as pd

    from safe_bc.metrics import clopper_pearson_upper, paired_to_reference

    rows = []
    for block, df in episodes.groupby("block", sort=True):
        paired = paired_to_reference(df, "expert", ["reward"]).set_index("method")
        for method, m in df.groupby("method", sort=False):
            k, n = int((m[crossing] > 0).sum()), len(m)
            row = {
                "block": "selection" if block == SELECTION_BLOCK else "fresh",
                "method": method,
                "episodes": n,
                "episodes_beyond": k,
                "beyond_ucb95": clopper_pearson_upper(k, n),
                "reward": float(m["reward"].mean()),
            }
            if method in paired.index:
                for c in ("d_reward", "d_reward_lo", "d_reward_hi"):
                    row[f"{c}_vs_expert"] = float(paired.loc[method, c])
            row["queries_per_episode"] = queries.get(method, float("nan"))
            deferred = m.get("deferred_steps")
            row["deferred_steps_per_episode"] = (
                float(deferred.mean())
                if deferred is not None and deferred.notna().any()
                else float("nan")
            )
            row["width"] = widths.get(method, float("nan"))
            rows.append(row)
    return pd.DataFrame(rows)


if __name__ == "__main__":
    raise SystemExit(main())
