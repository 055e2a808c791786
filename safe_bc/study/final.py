"""The study's final phase: the top trials retrained with more seeds and re-evaluated on fresh
tracks beside plain BC and the expert; the winner is chosen on this re-evaluation.

Design: each candidate is trained with ``final_train_seeds`` seeds (the first is the trial's
own, taken from its checkpoint), and each seed is evaluated on its own block of fresh tracks
(``final_tracks_per_seed``), the same blocks for every candidate, plain BC (same seeds,
trained like the first candidate with ``alpha = 0``) and the expert. Seeds are nested in
track blocks, so the two-level bootstrap (seeds, then tracks within a seed) fits the design;
for the same number of episodes it covers 3x the tracks of evaluating every seed on every
track, and an episode costs the same either way.

With stages (:meth:`StudySpec.stages`, e.g. ``StudySpec.improve``), every candidate's
net of every seed goes through them (its own ``<stage>.*`` settings, ``seed`` = the training
seed; in the driver, one run after the other, resumable under
``results/<study>/final_<stage>/``) and those agents are evaluated; plain BC and the expert
stay the references.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch

from safe_bc.bc.net import BCNet
from safe_bc.data.demos import Demonstrations
from safe_bc.distributed.evaluate import LOCKSTEP_ENVS, evaluate_policies
from safe_bc.distributed.rollouts import ChunkedRayRollouts
from safe_bc.distributed.runtime import cluster_cpus, ensure_ray
from safe_bc.distributed.train import train_many
from safe_bc.methods.experiment import RunConfig, train_run
from safe_bc.methods.stages import run_stage
from safe_bc.metrics import (
    certified_share,
    clopper_pearson_upper,
    paired_differences,
    summarize_policies,
)
from safe_bc.rollout.collect import stored_expert_config
from safe_bc.rollout.evaluate import EvalConfig, ExpertSource, NetSource
from safe_bc.study.final_store import FinalStore, agent_key, key_of
from safe_bc.study.spec import StudySpec, constraints, missed
from safe_bc.study.stop import deferred_stop, stop_point
from safe_bc.study.trial import (
    TrialJob,
    bounds_for,
    trial_threads,
    validation_demos,
    with_handover,
    with_seed,
)
from safe_bc.tasks import Bounds

PLAIN_BC = "plain_bc"
"""Method label of the alpha = 0 reference in the final table."""
EXPERT = "expert"
"""Method label of the expert in the final table."""


@dataclass(frozen=True)
class FinalOutcome:
    """What the final phase measured and chose."""

    table: pd.DataFrame
    """One row per method (candidate trial ids, ``plain_bc``, ``expert``): means and CIs of
    every metric, constraints, ``feasible``, ``n_train_seeds``, ``episodes_with_violation``."""
    episodes: pd.DataFrame
    """One row per evaluated episode (``method``, ``train_seed``, ``env_seed``, metrics)."""
    winner: str | None
    """Trial id of the winner: the best feasible candidate on the re-evaluation (else the
    least infeasible); ``None`` without candidates."""
    feasible: bool
    """Whether the winner met both constraints on the re-evaluation."""
    message: str
    """One line saying how the winner was chosen."""
    configs: dict[str, dict[str, Any]]
    """Method -> its run configuration (the first seed's)."""
    certified: str = ""
    """What the winner's fresh episodes certify: the one-sided Clopper-Pearson upper bound on
    its share of episodes beyond ``d_s`` (at the study's ``violation_bound``, else 95%)."""
    paired: pd.DataFrame = dataclasses.field(default_factory=pd.DataFrame)
    """Paired differences on the same tracks (:func:`final_paired`)."""
    seconds: dict[str, float] = dataclasses.field(default_factory=dict)
    """Wall-clock of this run's parts: ``train`` (storing the agents included), ``stages``,
    ``evaluation`` (storing the episodes included); empty when read back from the tables."""
    agents: dict[tuple[str, int], Any] = dataclasses.field(default_factory=dict)
    """``(method, training seed)`` -> the evaluated agent's policy source (before its
    handover), for the certification and the recommender; empty when read back."""
    models: dict[tuple[str, int], tuple[Any, RunConfig]] = dataclasses.field(default_factory=dict)
    """``(method, training seed)`` -> the trained net and its run configuration; empty when
    read back."""


def final_workers(spec: StudySpec) -> int:
    """Actors of the final phase: ``spec.final_workers``, or one per CPU of the cluster."""
    if spec.final_workers is not None:
        return spec.final_workers
    ensure_ray()
    return max(1, int(cluster_cpus()))


def _train(
    demos: Demonstrations,
    runs: list[RunConfig],
    workers: int,
    bounds: Bounds,
    progress: bool,
    on_done: Callable[[int, Any], None] | None = None,
    validation: Demonstrations | None = None,
) -> list[BCNet]:
    """Train ``runs``; ``on_done(i, result)`` as each finishes (see ``train_many``), each
    curve recording the loss on ``validation``."""
    if not runs:
        return []
    if workers == 0:  # in the driver, one thread per agent like the trials
        previous = torch.get_num_threads()
        try:
            out = []
            for i, r in enumerate(runs):
                torch.set_num_threads(r.bc.train.num_threads or 1)
                result = train_run(demos, r, action_bounds=bounds, validation=validation)[0]
                if on_done is not None:
                    on_done(i, result)
                out.append(result.model)
            return out
        finally:
            torch.set_num_threads(previous)
    trained = train_many(
        demos,
        runs,
        workers=workers,
        action_bounds=bounds,
        progress=progress,
        on_done=on_done,
        validation=validation,
    )
    return [result.model for result, _ in trained]


def final_phase(
    spec: StudySpec,
    job: TrialJob,
    candidates: pd.DataFrame,
    checkpoints: Mapping[str, BCNet],
    demos: Demonstrations,
    *,
    progress: bool = True,
    store: FinalStore | None = None,
    on_curve: Callable[[str, int, pd.DataFrame], None] | None = None,
) -> FinalOutcome:
    """Retrain ``candidates`` (rows of the trial table) with ``final_train_seeds`` seeds each,
    train plain BC with the same seeds, evaluate all of them and the expert on fresh tracks,
    and choose the winner on that evaluation.

    Args:
        checkpoints: trial id -> the trial's trained net (its own seed); a candidate without
            one is retrained for that seed too.
        store: where finished agents and evaluations are kept as they finish; those already
            there (an interrupted earlier run) are taken from it, not redone.
        on_curve: ``(method, seed, learning curve)`` of each agent this run retrains, as it
            finishes (the study's TensorBoard runs).
    """
    workers = final_workers(spec)
    threads = trial_threads(spec)
    seeds = [spec.base.bc.train.seed + i for i in range(spec.final_train_seeds)]
    cfgs: dict[str, RunConfig] = {
        str(row["trial_id"]): spec.run_config({k: row[k] for k in spec.params}, threads)
        for _, row in candidates.iterrows()
    }
    if not cfgs:
        empty = pd.DataFrame()
        return FinalOutcome(empty, empty, None, False, "no candidate to re-evaluate", {})
    first = next(iter(cfgs.values()))
    cfgs[PLAIN_BC] = spec.baseline_config(first)
    nets: dict[tuple[str, int], Any] = {}
    models: dict[tuple[str, int], tuple[BCNet, RunConfig]] = {}
    todo: list[tuple[str, int, RunConfig]] = []
    for method, cfg in cfgs.items():
        for s in seeds:
            if s == seeds[0] and method in checkpoints:
                nets[(method, s)] = NetSource.from_model(checkpoints[method], cfg.bc)
                models[(method, s)] = (checkpoints[method], cfg)
            else:
                run = with_seed(cfg, s)
                stored = store.agent(agent_key(run, job.demos)) if store is not None else None
                if stored is None:
                    todo.append((method, s, run))
                else:
                    nets[(method, s)] = NetSource.from_model(stored, run.bc)
                    models[(method, s)] = (stored, run)
    if progress:
        kept = len(cfgs) * len(seeds) - len(todo) - sum(m in checkpoints for m in cfgs)
        print(f"final phase: training {len(todo)} agents ({len(cfgs) - 1} candidates and plain "
              f"BC x {len(seeds)} seeds) on {max(workers, 1)} worker(s)"
              + (f"; {kept} finished before, taken from {store.root}" if kept else ""))  # fmt: skip

    def keep(i: int, result: Any) -> None:
        if store is not None:
            run = todo[i][2]
            store.save_agent(agent_key(run, job.demos), result.model, run)
        if on_curve is not None:
            on_curve(todo[i][0], todo[i][1], result.curve())
        stop_point()  # Ctrl-C / SIGTERM: stop now that this agent is kept

    runs = [r for *_, r in todo]
    clock = time.perf_counter()
    with deferred_stop():
        trained = _train(
            demos, runs, workers, bounds_for(job.demos), progress, keep, validation_demos(job)
        )
    for (method, s, run), model in zip(todo, trained, strict=True):
        nets[(method, s)] = NetSource.from_model(model, run.bc)
        models[(method, s)] = (model, run)
    seconds = {"train": time.perf_counter() - clock}
    clock = time.perf_counter()
    nets.update(_run_stages(spec, job, candidates, models, progress))
    seconds["stages"] = time.perf_counter() - clock
    clock = time.perf_counter()

    parts = _evaluate_final(
        spec, job, cfgs, seeds, candidates, nets, store, workers, threads, progress
    )
    seconds["evaluation"] = time.perf_counter() - clock
    episodes = pd.concat(parts, ignore_index=True)
    table, paired, confidence = _final_table(spec, job, episodes, cfgs)
    winner, feasible, message = choose_final(table)
    certified = ""
    if winner is not None and "episodes_with_violation" in table:
        row = table[table["method"] == winner].iloc[0]
        certified = certified_share(
            int(row["episodes_with_violation"]), int(row["n_episodes"]), confidence
        )
    configs = {m: c.to_dict() for m, c in cfgs.items()}
    return FinalOutcome(
        table, episodes, winner, feasible, message, configs, certified, paired, seconds,
        agents=dict(nets), models=dict(models),
    )  # fmt: skip


def _evaluate_final(
    spec: StudySpec,
    job: TrialJob,
    cfgs: Mapping[str, RunConfig],
    seeds: list[int],
    candidates: pd.DataFrame,
    nets: Mapping[tuple[str, int], Any],
    store: FinalStore | None,
    workers: int,
    threads: int,
    progress: bool,
) -> list[pd.DataFrame]:
    """Every agent (a candidate with the study's handover) and the expert on fresh tracks, one
    block of tracks per training seed; evaluations already in ``store`` are taken from it."""

    def _evaluated(method: str, seed: int) -> Any:
        """A candidate with the study's handover (the recommender); plain BC alone."""
        if spec.handover is None or method == PLAIN_BC:
            return nets[(method, seed)]
        return with_handover(nets[(method, seed)], job)

    per = spec.final_tracks_per_seed()
    expert = ExpertSource(stored_expert_config(Path(job.demos)))
    parts = []
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)  # in-process evaluation: more threads ran slower here
    try:
        for i, s in enumerate(seeds):
            sources: dict[str, Any] = {f"{m} seed={s}": _evaluated(m, s) for m in cfgs}
            sources[f"{EXPERT} block={i}"] = expert
            config = block_config(spec, spec.final_seed, i * per, per, workers)
            what = {
                f"{m} seed={s}": _agent_identity(spec, job, m, cfgs[m], s, candidates) for m in cfgs
            }
            what[f"{EXPERT} block={i}"] = ("expert", str(job.demos))
            # the config's repr leaves lockstep_forward out (keys made before it hold);
            # "batched" gives other episodes than "rows", so it is keyed when used
            forward = [] if config.lockstep_forward == "rows" else [config.lockstep_forward]
            keys = {
                name: key_of("episodes", what[name], config, list(job.cost_limits), *forward)
                for name in sources
            }
            done = stored_evaluations(store, keys)
            if progress:
                print(f"final phase: seed {s}, {spec.task().episodes_name} "
                      f"{i * per}..{(i + 1) * per - 1} of block "
                      f"{spec.final_seed}" + (f"; {len(done)} of {len(sources)} evaluations "
                      "finished before" if done else ""))  # fmt: skip
            ep = evaluate_block(sources, keys, done, config, job.cost_limits, store, progress, s)
            parts.append(ep)
    finally:
        torch.set_num_threads(previous)
    return parts


def _final_table(
    spec: StudySpec, job: TrialJob, episodes: pd.DataFrame, cfgs: Mapping[str, RunConfig]
) -> tuple[pd.DataFrame, pd.DataFrame, float]:
    """The final table (a row per method in candidate order, then the expert, with its
    constraints, feasibility, role and the violation share's upper bound), the paired
    summaries and the bound's confidence."""
    table, paired = final_summaries(episodes, cfgs, spec.final_seed)
    order = {m: i for i, m in enumerate([*cfgs, EXPERT])}
    table = table.sort_values("method", key=lambda c: c.map(order)).reset_index(drop=True)
    if "deferred_share" in episodes:
        table["deferred_share"] = table["method"].map(
            episodes.groupby("method")["deferred_share"].mean()
        )
    cons = pd.DataFrame([constraints(r, job.limits) for r in table.to_dict("records")])
    table = pd.concat([table, cons], axis=1)
    table["feasible"] = table["constraint"] <= 0
    table["role"] = ["candidate" if m in cfgs and m != PLAIN_BC else m for m in table["method"]]
    confidence = 0.95 if spec.violation_bound is None else spec.violation_bound
    if "episodes_with_violation" in table:
        table["violation_share_ucb"] = [
            clopper_pearson_upper(int(k), int(n), confidence)
            for k, n in zip(table["episodes_with_violation"], table["n_episodes"], strict=True)
        ]
    return table, paired, confidence


def block_config(spec: StudySpec, block: int, first: int, n: int, workers: int) -> EvalConfig:
    """Episodes ``first .. first + n - 1`` of held-out block ``block`` in the study's env."""
    return EvalConfig(
        episodes=n,
        first_episode=first,
        workers=workers,
        seed=block,
        env=spec.env,
        max_steps=spec.max_steps,
        eps=spec.critical_eps,
    )


def stored_evaluations(store: FinalStore | None, keys: Mapping[str, str]) -> dict[str, Any]:
    """Name -> its episodes, for the evaluations of ``keys`` already in ``store``."""
    done = {n: store.episodes(k) for n, k in keys.items()} if store is not None else {}
    return {n: ep for n, ep in done.items() if ep is not None}


def evaluate_block(
    sources: Mapping[str, Any],
    keys: Mapping[str, str],
    done: Mapping[str, pd.DataFrame],
    config: EvalConfig,
    limits: Any,
    store: FinalStore | None,
    progress: bool,
    train_seed: int,
) -> pd.DataFrame:
    """Every source's episodes on one block of fresh tracks (``config``): those in ``done``
    (:func:`stored_evaluations`) as they are, the rest evaluated in lockstep and kept in
    ``store`` under their ``keys`` (a Ctrl-C or SIGTERM stops once they are kept). Rows in
    source order, with ``method`` (the name's first word) and ``train_seed``."""
    left = {n: src for n, src in sources.items() if n not in done}
    found = []
    if left:
        with deferred_stop():  # stops after the evaluation, once it is stored
            eps, _ = evaluate_policies(  # its rows only: the summaries come later
                left, config, thresholds=np.asarray(limits), progress=progress,
                envs_per_worker=LOCKSTEP_ENVS)  # fmt: skip
            for name in left:
                mine = eps[eps["policy"] == name].reset_index(drop=True)
                if store is not None:
                    store.save_episodes(keys[name], mine)
                found.append(mine)
    ep = pd.concat(
        [*(done[n].assign(policy=n) for n in sources if n in done), *found], ignore_index=True
    )
    order = {n: j for j, n in enumerate(sources)}
    ep = ep.sort_values("policy", key=lambda c: c.map(order), kind="stable")
    ep = ep.reset_index(drop=True)
    ep.insert(0, "train_seed", train_seed)
    ep.insert(0, "method", ep["policy"].str.split(" ").str[0])
    return ep


def _agent_identity(
    spec: StudySpec,
    job: TrialJob,
    method: str,
    cfg: RunConfig,
    seed: int,
    candidates: pd.DataFrame,
) -> tuple[Any, ...]:
    """What an evaluated agent is, independent of trial ids: its run (seed included), the
    demonstrations and, for a candidate, its stages' settings."""
    stages: list[Any] = []
    if method != PLAIN_BC:
        row = candidates[candidates["trial_id"].astype(str) == method].iloc[0]
        params = {k: row[k] for k in spec.params}
        stages = [
            (stage.name, dataclasses.asdict(spec.stage_config(stage.name, params, seed=seed)))
            for stage in spec.stages()
        ]
    what: tuple[Any, ...] = ("agent", with_seed(cfg, seed).to_dict(), str(job.demos), stages)
    if spec.handover is not None and method != PLAIN_BC:
        what += (("handover", spec.handover.to_dict(), "lockstep"),)  # (evaluated in lockstep)
    return what


def bootstrap_labels(cfgs: Mapping[str, RunConfig | Mapping[str, Any]]) -> dict[str, str]:
    """Method -> ``"candidate:<digest>"``, a label that depends only on the method's
    configuration (SHA-256 of its sorted JSON): the same study rerun gives its candidates the
    same labels, hence the same bootstrap draws (:func:`safe_bc.metrics.keyed_rng`), whatever
    trial ids Tune hands out.

    >>> from safe_bc.methods.experiment import RunConfig
    >>> a = bootstrap_labels({"3f2a9c01": RunConfig()})
    >>> b = bootstrap_labels({"77aa0b12": RunConfig()})
    >>> a["3f2a9c01"] == b["77aa0b12"] and a["3f2a9c01"].startswith("candidate:")
    True
    """
    out = {}
    for method, cfg in cfgs.items():  # a RunConfig, or its to_dict() as a table's metadata holds
        as_dict = cfg.to_dict() if isinstance(cfg, RunConfig) else cfg
        text = json.dumps(as_dict, sort_keys=True, default=str)
        out[method] = "candidate:" + hashlib.sha256(text.encode()).hexdigest()[:16]
    if len(set(out.values())) != len(out):
        raise ValueError("two final candidates have the same configuration")
    return out


def final_summaries(
    episodes: pd.DataFrame, cfgs: Mapping[str, RunConfig | Mapping[str, Any]], seed: int
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The final phase's per-method table (:func:`safe_bc.metrics.summarize_policies`) and its
    paired differences (:func:`final_paired`), bootstrap seed ``seed``.

    The bootstrap streams are keyed by method name, and the candidates' names are Tune's trial
    ids, random per run; so their intervals are drawn under :func:`bootstrap_labels` (made from
    their configurations) and the rows then carry the trial ids again. A rerun of the same
    study thus gives the same intervals.
    """
    labels = bootstrap_labels({m: c for m, c in cfgs.items() if m != PLAIN_BC})
    by_label = {label: method for method, label in labels.items()}
    keyed = episodes.assign(method=episodes["method"].replace(labels))
    table = summarize_policies(keyed, ["method"], group="train_seed", seed=seed)
    table["method"] = table["method"].replace(by_label)
    paired = final_paired(keyed, seed=seed)
    if len(paired):
        paired["method"] = paired["method"].replace(by_label)
    return table, paired


PAIRED_METRICS = ("reward", "safety_mean", "violation_steps", "any_violation")
"""What :func:`final_paired` compares (those the episodes hold)."""


def final_paired(episodes: pd.DataFrame, seed: int) -> pd.DataFrame:
    """Paired differences of the final phase: every method against the expert, and every
    candidate against plain BC, on the same (training seed, track) pairs (the expert and plain
    BC ran on every seed's tracks), with the two-level bootstrap that fits the nested design
    (:func:`safe_bc.metrics.paired_differences`, bootstrap seed ``seed``). One row per
    (``method``, ``vs``): ``d_<metric>`` and its CI, ``n_pairs``.
    """
    metrics = [m for m in PAIRED_METRICS if m in episodes and episodes[m].notna().any()]
    parts = []
    for baseline in (EXPERT, PLAIN_BC):
        if baseline not in set(episodes["method"]):
            continue
        rows = episodes if baseline == EXPERT else episodes[episodes["method"] != EXPERT]
        diff = paired_differences(rows, baseline, metrics, seed=seed)
        if len(diff):
            parts.append(diff.assign(vs=baseline))
    if not parts:
        return pd.DataFrame()
    out = pd.concat(parts, ignore_index=True)
    return out[["method", "vs", *[c for c in out if c not in ("method", "vs")]]]


def _run_stages(
    spec: StudySpec,
    job: TrialJob,
    candidates: pd.DataFrame,
    models: Mapping[tuple[str, int], tuple[BCNet, RunConfig]],
    progress: bool,
) -> dict[tuple[str, int], Any]:
    """Every candidate's and seed's agent after the study's stages (plain BC is left as it
    is), each stage in its folder ``results/<study>/final_<stage>/<trial>/seed<k>/``."""
    stages = spec.stages()
    if not stages:
        return {}
    params = {str(r["trial_id"]): {k: r[k] for k in spec.params} for _, r in candidates.iterrows()}
    agents: dict[tuple[str, int], Any] = {k: m for k, (m, _) in models.items() if k[0] in params}
    for stage in stages:
        name = stage.name
        root = spec.results / spec.name / f"final_{name}"
        for (method, s), agent in agents.items():
            if progress:
                print(f"final phase: {stage.label or name} {method} seed {s}")
            agents[(method, s)], _ = run_stage(
                stage, spec.stage_config(name, params[method], seed=s), agent,
                models[(method, s)][1],
                job.demos, spec.env.env_id, root / method / f"seed{s}",
                parallel=ChunkedRayRollouts,
            )  # fmt: skip
    return agents


def missed_constraints(table: pd.DataFrame) -> list[str]:
    """One line per candidate of the final table that misses a constraint, naming what it
    missed and by how much (the constraint's value, ``> 0`` when missed); none: every
    candidate is feasible. Pure.

    >>> t = pd.DataFrame({"method": ["a", "b"], "role": ["candidate"] * 2,
    ...     "constraint": [0.2, -1.0], "constraint_safety": [0.2, -1.0],
    ...     "constraint_violation": [-0.1, -1.0], "constraint_deferral": [-1.0, -1.0]})
    >>> missed_constraints(t)
    ['candidate a: safety mean below the threshold (constraint_safety +0.2)']
    """
    lines = []
    for row in table[table["role"] == "candidate"].to_dict("records"):
        if float(row["constraint"]) <= 0:
            continue
        what = "; ".join(missed(row)) or "a constraint is NaN"
        lines.append(f"candidate {row['method']}: {what}")
    return lines


def choose_final(table: pd.DataFrame) -> tuple[str | None, bool, str]:
    """The best feasible candidate by re-evaluated reward, else the least infeasible one.

    >>> t = pd.DataFrame({"method": ["a", "b", "plain_bc"], "role": ["candidate"] * 2 +
    ...     ["plain_bc"], "reward": [900.0, 950.0, 990.0], "constraint": [-1.0, 0.5, -2.0]})
    >>> choose_final(t)[:2]
    ('a', True)
    """
    cands = table[table["role"] == "candidate"]
    cands = cands[np.isfinite(cands["reward"].astype(float))]
    if cands.empty:
        return None, False, "no candidate finished its re-evaluation"
    ok = cands[cands["constraint"] <= 0]
    if not ok.empty:
        best = ok.sort_values(["reward", "method"], ascending=[False, True]).iloc[0]
        return (
            str(best["method"]),
            True,
            f"winner {best['method']}: highest re-evaluated reward {best['reward']:.1f} among "
            f"{len(ok)}/{len(cands)} feasible candidates",
        )
    best = cands.sort_values(["constraint", "reward"], ascending=[True, False]).iloc[0]
    return (
        str(best["method"]),
        False,
        f"no candidate met every constraint on the re-evaluation: closest is {best['method']} "
        f"(constraint {best['constraint']:.3g}, reward {best['reward']:.1f})",
    )
