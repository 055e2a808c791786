"""``make peers``'s two steps in safe_bc's environment, around ``peers/osrl_train.py``.

* :func:`prepare`: the task's demonstrations as DSRL's dataset dict (``RUNS/dsrl.npz``,
  :func:`safe_bc.peers.data.dsrl_from_demos`) and the training plan (``RUNS/plan.json``,
  :func:`safe_bc.peers.plan.training_plan`).
* :func:`evaluate`: the peers' exported actors (``RUNS/actors/``) beside safe_bc's own methods
  (plain BC, safety imitation and its BC-Safe, trained here with the same training seeds), the
  task's recommender where one is committed, and the expert, all with safe_bc's one evaluation
  path (:func:`safe_bc.distributed.evaluate.evaluate`) on the same fresh patients (``block``),
  at the demonstrations' own ``d_s``; then the table (:mod:`safe_bc.peers.table`) with reward
  differences paired against the expert, written to ``OUT``.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from safe_bc.peers.data import dsrl_from_demos, kept_by_budget
from safe_bc.peers.plan import (
    CDT_NOTE,
    OSRL_LICENCE,
    OSRL_VERSION,
    budget_lines,
    training_plan,
)
from safe_bc.peers.table import markdown_table, peers_table, policy_key, split_policies

BLOCK = 95
"""The fresh block of held-out patients the committed table runs on (new to every table and
study of the clinic; the car's third design drives tracks of block 95, other envs)."""
COST_LIMIT = 1.0
"""The peers' cost budget per episode, in critical-zone transitions: the clinic's programmes
have 0 (122 of 150) to 5; BC-Safe keeps the 136 within 1."""
REFERENCE = "expert"
"""The row the paired differences are against (the task's expert; the clinic's guideline)."""


def prepare(
    demos: Path,
    runs: Path,
    *,
    seeds: tuple[int, ...] = (0, 1, 2),
    cost_limit: float = COST_LIMIT,
    eps: float | None = None,
    scale: float = 1.0,
) -> str:
    """Write ``runs/dsrl.npz`` and ``runs/plan.json``; the value: one line of what they hold."""
    from safe_bc.data.store import data_digest

    data, info = dsrl_from_demos(demos, eps=eps)
    plan = training_plan(
        state_dim=info["state_dim"], action_dim=info["action_dim"],
        episode_len=info["episode_len"], cost_limit=cost_limit, seeds=seeds, scale=scale,
    )  # fmt: skip
    kept = kept_by_budget(info["episode_costs"], cost_limit)
    plan.update(
        action_low=info["action_low"], action_high=info["action_high"],
        dataset={"demos": str(demos), "digest": data_digest(demos),
                 **{k: v for k, v in info.items() if k != "episode_costs"},
                 "episodes_within_budget": kept},
    )  # fmt: skip
    runs.mkdir(parents=True, exist_ok=True)
    np.savez(runs / "dsrl.npz", **data)
    (runs / "plan.json").write_text(json.dumps(plan, indent=1) + "\n")
    return (
        f"{runs}/dsrl.npz: {info['transitions']} transitions of {info['episodes']} episodes, "
        f"{info['cost_transitions']} with cost 1 (critical zone, eps {info['eps']:g}); "
        f"{kept} episodes within the budget {cost_limit:g}"
    )


@dataclass(frozen=True)
class SafeBCRow:
    """One of safe_bc's own methods, trained per seed here."""

    name: str
    selection: Any
    note: str = ""


def safe_bc_rows(eps: float) -> list[SafeBCRow]:
    """safe_bc's methods beside the peers: plain BC, safety imitation (the clinic's recommender
    starts from alpha 0.5, eps 0.05) and safe_bc's own re-implementation of BC-Safe."""
    from safe_bc.selection import SelectionConfig

    return [
        SafeBCRow("safe_bc plain BC", SelectionConfig(eps=eps, alpha=0.0)),
        SafeBCRow("safe_bc safety imitation", SelectionConfig(eps=eps, alpha=0.5)),
        SafeBCRow("safe_bc BC-Safe", SelectionConfig(eps=eps, mode="bc_safe")),
    ]


@dataclass
class Sources:
    """What :func:`evaluate` evaluates: policy sources by key and the table's rows."""

    sources: dict[str, Any] = field(default_factory=dict)
    rows: dict[str, dict[str, Any]] = field(default_factory=dict)


def _peer_sources(runs: Path, plan: dict, trained: dict, out: Sources) -> None:
    from safe_bc.peers.bridge import ScriptedSource

    for p in plan["peers"]:
        for s in plan["seeds"]:
            path = runs / "actors" / f"{p['name']}_seed{s}.pt"
            if not path.exists():
                raise FileNotFoundError(f"{path}: not trained; run peers/osrl_train.py first")
            out.sources[policy_key(p["name"], s)] = ScriptedSource.from_file(path)
        rec = trained.get(f"{p['name']}_seed{plan['seeds'][0]}", {})
        kept = f", {rec['episodes']} of {rec['episodes_of']} episodes" if "episodes" in rec else ""
        out.rows[p["name"]] = {
            "source": f"OSRL {OSRL_VERSION} ({p['algorithm']})",
            "budget": f"{p['updates']:,} of {p['osrl_updates']:,} updates{kept}",
        }


def _safe_bc_sources(demos: Path, eps: float, seeds: list[int], out: Sources) -> None:
    from dataclasses import replace

    from safe_bc.bc import BCConfig
    from safe_bc.data.store import load_demonstrations
    from safe_bc.methods.experiment import train_run
    from safe_bc.rollout.evaluate import NetSource
    from safe_bc.run_config import RunConfig
    from safe_bc.tasks import dataset_action_bounds

    data = load_demonstrations(demos)
    bounds = dataset_action_bounds(demos)
    base = BCConfig()
    for row in safe_bc_rows(eps):
        for s in seeds:
            bc = replace(base, train=replace(base.train, seed=int(s)))
            result, _ = train_run(data, RunConfig(row.selection, bc), action_bounds=bounds)
            out.sources[policy_key(row.name, s)] = NetSource.from_model(result.model, bc)
        out.rows[row.name] = {"source": "safe_bc", "budget": f"{base.train.batches:,} batches"}


def _recommender_sources(path: Path, task: str, demos: Path, out: Sources) -> None:
    from safe_bc.study.recommender import load_recommender

    rec = load_recommender(path, task=task, demos=demos)
    name = "safe_bc recommender (as loaded)"
    for s in rec.card.seeds:
        out.sources[policy_key(name, s)] = rec.source(s)
    out.rows[name] = {
        "source": f"safe_bc ({path}: load_recommender, its agents and handover)",
        "budget": f"study {rec.card.source.get('study', '?')}",
    }


def evaluate(
    task: str,
    demos: Path,
    runs: Path,
    out: Path,
    *,
    block: int = BLOCK,
    patients: int = 200,
    recommender: Path | None = None,
    workers: int = 0,
) -> str:
    """Evaluate every row on ``patients`` fresh patients of ``block`` and write ``out``'s
    ``table.parquet``, ``episodes.parquet`` and ``table.md``; the value: the Markdown."""
    from safe_bc.data.provenance import run_metadata
    from safe_bc.data.store import read_meta, write_table_atomic
    from safe_bc.distributed.evaluate import evaluate as run_evaluate
    from safe_bc.export.limits import dataset_zone
    from safe_bc.rollout.collect import expert_for
    from safe_bc.rollout.evaluate import EvalConfig, ExpertSource
    from safe_bc.tasks import task_defaults

    start = time.perf_counter()
    spec = task_defaults(task)
    plan = json.loads((runs / "plan.json").read_text())
    trained = json.loads((runs / "train.json").read_text())
    meta = read_meta(demos)
    zone = dataset_zone(demos, meta)
    digest = plan["dataset"]["digest"]
    from safe_bc.data.store import data_digest

    if data_digest(demos) != digest:
        raise ValueError(f"{runs}: the peers were trained on other demonstrations than {demos}")
    found = Sources()
    found.sources[REFERENCE] = ExpertSource(expert_for(demos, meta.env_id))
    found.rows[REFERENCE] = {"source": "the task's expert", "budget": ""}
    _peer_sources(runs, plan, trained, found)
    _safe_bc_sources(demos, spec.eps, plan["seeds"], found)
    if recommender is not None and (recommender / "recommender.json").exists():
        _recommender_sources(recommender, task, demos, found)
    cfg = EvalConfig(episodes=patients, workers=workers, seed=block, env=spec.env, eps=spec.eps)
    result = run_evaluate(found.sources, cfg, np.asarray(zone.limits), progress=False)
    episodes = split_policies(result.episodes)
    table = peers_table(episodes, REFERENCE, found.rows)
    seconds = time.perf_counter() - start
    per_peer = {}
    for rec in trained.values():
        agg = per_peer.setdefault(rec["peer"], {"updates": rec["updates"], "seeds": 0,
                                                "osrl_updates": rec["osrl_updates"],
                                                "seconds": 0.0})  # fmt: skip
        agg["seeds"] += 1
        agg["seconds"] += rec["seconds"]
    for agg in per_peer.values():
        agg["seconds_per_update"] = agg["seconds"] / agg["seeds"] / agg["updates"]
    record = run_metadata(
        task=task, demos=str(demos), demos_digest=digest, block=block, patients=patients,
        train_seeds=plan["seeds"], cost_limit=plan["cost_limit"], cost_rule="critical",
        eps=zone.eps, d_s=dict(zip(meta.safety_dims, map(float, zone.limits), strict=True)),
        osrl_version=OSRL_VERSION, licence=OSRL_LICENCE, trained=per_peer,
        evaluate_seconds=seconds,
    )  # fmt: skip
    out.mkdir(parents=True, exist_ok=True)
    write_table_atomic(out / "table.parquet", table, record)
    keep = [c for c in ("method", "train_seed", "env_seed", "reward", "safety_mean", "beyond",
                        "any_violation", "deferred_share") if c in episodes]  # fmt: skip
    write_table_atomic(out / "episodes.parquet", episodes[keep], record)
    text = _markdown(table, record, plan, spec, per_peer, recommender)
    (out / "table.md").write_text(text)
    return text


def _markdown(table, record, plan, spec, per_peer, recommender) -> str:
    n, seeds = record["patients"], len(record["train_seeds"])
    train_s = sum(p["seconds"] for p in per_peer.values())
    d_s = ", ".join(f"{d} {v:.3f}" for d, v in record["d_s"].items())
    lines = [
        f"# OSRL's own code beside safe_bc's methods: {record['task']}",
        "",
        f"Every row on the same {n} fresh {spec.episodes_name} (held-out block {record['block']}, "
        f"new to every table of the task), {seeds} training seeds each (the expert once), "
        "evaluated by safe_bc's one evaluation path at the demonstrations' own limits "
        f"d_s ({d_s}). Reward: mean with a 95% crossed bootstrap CI over training seeds x "
        f"{spec.episodes_name}; the difference to the {REFERENCE} is paired on the same "
        f"{spec.episodes_name}. Beyond d_s: {spec.episodes_name} that reached a state beyond "
        "d_s; its bound is the 95% one-sided Clopper-Pearson upper bound.",
        "",
        *markdown_table(table, REFERENCE),
        "",
        "## How the peers were trained",
        "",
        f"- Code: osrl-lib {OSRL_VERSION} from PyPI, in an environment of its own (`make "
        "peers-env`; its pins cannot be met beside safe_bc), run by `peers/osrl_train.py`.",
        f"- Data: the demonstrations `{record['demos']}` ({record['demos_digest'][:15]}...) in "
        f"DSRL's layout, {plan['dataset']['transitions']} transitions, the scalar cost the "
        f"critical-zone indicator (c_s >= d_s - eps, eps {record['eps']:g}): "
        f"{plan['dataset']['cost_transitions']} transitions with cost 1 (docs/interop.md).",
        f"- Cost budget per episode: {plan['cost_limit']:g} critical-zone transition(s) "
        f"({plan['dataset']['episodes_within_budget']} of {plan['dataset']['episodes']} "
        "demonstration episodes are within it); OSRL's example configs' other settings "
        "(networks, learning rates, batch 512, reward scale 0.1).",
        "- Budgets, and why not OSRL's defaults: " + "; ".join(budget_lines(per_peer)) + ".",
        f"- {CDT_NOTE}",
        f"- Licence: {OSRL_LICENCE}",
        "",
        f"Run: `make peers` ({record['git_revision'][:12]}, {record.get('cpu_model', 'CPU')}, "
        f"{record['cpus']} CPUs): the peers' training {train_s / 60:.1f} min, safe_bc's training "
        f"and the evaluation {record['evaluate_seconds'] / 60:.1f} min.",
        "",
    ]
    return "\n".join(lines)


__all__ = ["BLOCK", "COST_LIMIT", "REFERENCE", "evaluate", "prepare", "safe_bc_rows"]
