"""Run a handover measurement (:class:`safe_bc.compare.handover_choice.HandoverChoice`, a file such
as
``tune_jobs/handover/rehab.py`` defining ``CHOICE``): every candidate handover over the
recommender's agents, and the expert, on the same selection episodes; writes
``episodes.parquet``, ``choice.parquet`` (one row per candidate) and ``choice.md`` with the
row the file's rule picks.

    python -m scripts.handover_choice tune_jobs/handover/rehab.py [--workers N]

Episodes run one env at a time (the same rows on any CPU). A rerun reuses the candidates whose
episodes a previous run wrote (``parts/``, keyed by the candidate and the settings).
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from safe_bc.compare.handover_choice import (
    EXPERT,
    RULE_TEXT,
    HandoverChoice,
    candidate_label,
    choice_table,
    choose,
)
from safe_bc.data.atomic import write_text_atomic
from safe_bc.data.provenance import run_metadata
from safe_bc.data.store import read_table, write_table_atomic
from safe_bc.distributed.evaluate import evaluate_policies
from safe_bc.report import markdown_table
from safe_bc.rollout.collect import expert_config_from_dict
from safe_bc.rollout.config import EvalConfig
from safe_bc.rollout.evaluate import ExpertSource, NetSource
from safe_bc.rollout.handover import handover_source
from safe_bc.study.recommender import load_recommender
from safe_bc.tasks import task_defaults


def load_choice(path: Path) -> HandoverChoice:
    """The ``CHOICE`` a measurement file defines."""
    spec = importlib.util.spec_from_file_location(f"handover_choice_{path.stem}", path)
    if spec is None or spec.loader is None:
        raise SystemExit(f"{path}: not a Python file")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    choice = getattr(module, "CHOICE", None)
    if not isinstance(choice, HandoverChoice):
        raise SystemExit(f"{path}: defines no CHOICE = HandoverChoice(...)")
    return choice


def _key(*parts: object) -> str:
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:16]


def run(choice: HandoverChoice, workers: int, command: str) -> str:
    """Evaluate every candidate (and the expert) and write the tables; the summary lines."""
    rec = load_recommender(choice.recommender)
    task = task_defaults(rec.card.task)
    expert_cfg = expert_config_from_dict(rec.card.expert)
    limits = np.asarray(rec.limits)
    config = EvalConfig(
        episodes=choice.episodes, workers=workers, seed=choice.eval_seed, env=task.env,
        eps=task.eps,
    )  # fmt: skip
    settings = {"episodes": choice.episodes, "block": choice.eval_seed, "limits": limits.tolist()}
    parts_dir = choice.out / "parts"
    parts_dir.mkdir(parents=True, exist_ok=True)
    jobs: list[tuple[str, int, dict]] = [(EXPERT, -1, {})]
    jobs += [
        (candidate_label(i), s, h.to_dict())
        for i, h in enumerate(choice.candidates)
        for s in rec.card.seeds
    ]
    frames = []
    for n, (label, seed, handover) in enumerate(jobs, 1):
        what = (label, seed, handover, settings, rec.card.to_dict().get("card_sha256"))
        part = parts_dir / f"{label}_seed{seed}_{_key(what)}.parquet"
        if part.is_file():
            frames.append(read_table(part)[0])
            continue
        if label == EXPERT:
            source = ExpertSource(expert_cfg)
        else:
            h = choice.candidates[int(label[1:])]
            model, cfg = rec.agents[seed]
            agent = NetSource.from_model(model, cfg)
            source = handover_source(agent, h, expert_cfg, limits, rec.dims)
        episodes, _ = evaluate_policies({label: source}, config, thresholds=limits, progress=False)
        episodes = episodes.rename(columns={"policy": "method"})
        episodes.insert(1, "train_seed", seed)
        if "deferred_share" not in episodes:
            episodes["deferred_share"] = np.nan
        write_table_atomic(part, episodes, {"what": list(what)})
        frames.append(episodes)
        print(f"[{n}/{len(jobs)}] {label} seed {seed}: {len(episodes)} episodes", flush=True)
    episodes = pd.concat(frames, ignore_index=True)
    table = choice_table(episodes, choice)
    picked = choose(table, choice)
    meta = run_metadata(
        command=command,
        choice=choice.name,
        rule=choice.rule,
        deferred_limit=choice.deferred_limit,
        eval_seed=choice.eval_seed,
        episodes_per_seed=choice.episodes,
        recommender=str(choice.recommender),
        recommender_card={k: rec.card.to_dict()[k] for k in ("task", "limits", "demos", "seeds")},
        candidates=[h.to_dict() for h in choice.candidates],
        chosen=None if picked is None else choice.candidates[picked].to_dict(),
    )
    write_table_atomic(choice.out / "episodes.parquet", episodes, meta)
    write_table_atomic(choice.out / "choice.parquet", table, meta)
    verdict = (
        "no candidate qualifies"
        if picked is None
        else f"chosen: {candidate_label(picked)}, {choice.candidates[picked].label()}"
    )
    seeds = len(rec.card.seeds)
    cols = ["candidate", "handover", "episodes", "episodes_beyond", "beyond_ucb95",
            "deferred_share", "reward", "d_reward_vs_expert", "d_reward_lo",
            "d_reward_hi"]  # fmt: skip
    shown = table[cols].copy()
    text = "\n".join(
        [
            f"# Handover choice: {choice.name}",
            "",
            f"Every candidate over the agents of `{choice.recommender}` ({seeds} training seeds x "
            f"{choice.episodes} selection episodes of held-out block {choice.eval_seed}, the same "
            f"episodes for every candidate and seed), the expert alone on the same episodes. Rule, "
            f"fixed before the run ({choice.rule}): {RULE_TEXT[choice.rule]} (deferred-share "
            f"limit {choice.deferred_limit:g}). d_reward: paired with the expert on the same "
            f"episodes, crossed 95% bootstrap CI (training seeds x episodes).",
            "",
            f"**{verdict}**",
            "",
            markdown_table(shown.round(4).values.tolist(), cols),
            "",
            f"Made by `{command}`; code {str(meta.get('git_revision', '?'))[:12]}, "
            f"{meta.get('cpu_model', '?')} ({meta.get('cpus', '?')} CPUs).",
            "",
        ]
    )
    write_text_atomic(choice.out / "choice.md", text)
    return f"{verdict}\nwrote {choice.out}/choice.md, choice.parquet, episodes.parquet"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("file", type=Path, help="a measurement file defining CHOICE")
    parser.add_argument("--workers", type=int, default=0, help="Ray actors (0: this process)")
    args = parser.parse_args(argv)
    if not args.file.is_file():
        raise SystemExit(f"{args.file}: no such file")
    given = sys.argv[1:] if argv is None else argv
    command = "python -m scripts.handover_choice " + " ".join(given)
    print(run(load_choice(args.file), args.workers, command))


if __name__ == "__main__":
    main()
