"""The study's certification: the winner, chosen by the final phase, evaluated on a block of
fresh tracks that chose nothing, with its handover and alone, beside the expert on the same
tracks; its certificate says what those episodes support.

Design: each of the winner's training seeds on its own tracks of block ``certify_seed``
(``certify_episodes`` split evenly over the seeds), the expert on every seed's tracks (paired
differences), the same two-level bootstrap as the final phase (seeds, then tracks).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch

from safe_bc.metrics import clopper_pearson_upper, episodes_beyond, summarize_policies
from safe_bc.rollout.collect import stored_expert_config
from safe_bc.rollout.evaluate import ExpertSource
from safe_bc.study.final import (
    block_config,
    evaluate_block,
    final_paired,
    stored_evaluations,
)
from safe_bc.study.final_store import FinalStore, key_of
from safe_bc.study.spec import StudySpec
from safe_bc.study.trial import TrialJob, trial_threads, with_handover

RECOMMENDER = "recommender"
"""Method label of the winner with its handover."""
AGENT_ALONE = "agent_alone"
"""Method label of the winner's agent acting everywhere."""
EXPERT = "expert"
"""Method label of the expert."""

PAIRED = ("d_reward", "d_reward_lo", "d_reward_hi")
"""The reward difference to the expert on the same tracks and its 95% CI."""
GOAL_BOUND = 0.02
"""The certificate's goal for the one-sided 95% bound on the share of episodes beyond d_s."""
GOAL_DEFERRED = 0.05
"""The certificate's goal for the mean share of steps the expert acted (the recommender
must mostly recommend, not hand over) where the study sets no ``deferred_share_limit`` of its
own; a study that does is held to its limit (the clinic's 10%)."""


@dataclass(frozen=True)
class Certification:
    """The certification's episodes, table and certificate."""

    episodes: pd.DataFrame
    """One row per episode: ``method``, ``train_seed``, ``env_seed``, the metrics."""
    table: pd.DataFrame
    """Per method: the metric means with their CIs, ``episodes_beyond``, ``beyond_ucb95``,
    ``deferred_share``, ``d_reward`` against the expert with its CI."""
    certificate: dict[str, Any]
    """The recommender's numbers and the goals they meet (JSON-able)."""
    seconds: float = 0.0
    """Wall-clock of this run's evaluations."""
    per_seed: pd.DataFrame = field(default_factory=pd.DataFrame)
    """Mean reward per method and training seed."""


crossed = episodes_beyond
"""The certificate's crossings: :func:`safe_bc.metrics.episodes_beyond`."""


def certify(
    spec: StudySpec,
    job: TrialJob,
    agents: Mapping[int, Any],
    *,
    workers: int,
    store: FinalStore | None = None,
    identity: Any = None,
    progress: bool = True,
) -> Certification:
    """Evaluate the winner's ``agents`` (training seed -> its agent's policy source) with the
    study's handover and alone, and the expert, on block ``spec.certify_seed``.

    ``identity``: what the agents are (their run configuration), the key of their stored
    evaluations in ``store`` (a rerun takes finished ones from it)."""
    seeds = sorted(agents)
    per = -(-spec.certify_episodes // len(seeds))
    expert = ExpertSource(stored_expert_config(Path(job.demos)))
    threads = trial_threads(spec)
    parts = []
    clock = time.perf_counter()
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        for i, s in enumerate(seeds):
            sources: dict[str, Any] = {}
            if spec.handover is not None:
                sources[f"{RECOMMENDER} seed={s}"] = with_handover(agents[s], job)
            sources[f"{AGENT_ALONE} seed={s}"] = agents[s]
            sources[f"{EXPERT} seed={s}"] = expert
            config = block_config(spec, spec.certify_seed, i * per, per, workers)
            handover = None if spec.handover is None else spec.handover.to_dict()
            what = {
                f"{RECOMMENDER} seed={s}": ("recommender", identity, s, handover, "lockstep"),
                f"{AGENT_ALONE} seed={s}": ("agent", identity, s),
                f"{EXPERT} seed={s}": ("expert", str(job.demos)),
            }
            keys = {
                n: key_of("certify", what[n], config, list(job.cost_limits), "batched")
                for n in sources
            }
            done = stored_evaluations(store, keys)
            if progress:
                print(
                    f"certification: seed {s}, {spec.task().episodes_name} "
                    f"{i * per}..{(i + 1) * per - 1} of block "
                    f"{spec.certify_seed}"
                    + (f"; {len(done)} of {len(sources)} finished before" if done else "")
                )
            ep = evaluate_block(sources, keys, done, config, job.cost_limits, store, progress, s)
            parts.append(ep)
    finally:
        torch.set_num_threads(previous)
    seconds = time.perf_counter() - clock
    episodes = pd.concat(parts, ignore_index=True)
    table, per_seed, certificate = summarize_certification(episodes, spec)
    return Certification(episodes, table, certificate, seconds, per_seed)


def summarize_certification(
    episodes: pd.DataFrame, spec: StudySpec
) -> tuple[pd.DataFrame, pd.DataFrame, dict[str, Any]]:
    """The certification's table, per-seed rewards and certificate from its episodes (pure:
    rerun on the committed episodes, it gives the committed numbers)."""
    seed = spec.certify_seed
    table = summarize_policies(episodes, ["method"], group="train_seed", seed=seed)
    order = {m: i for i, m in enumerate([RECOMMENDER, AGENT_ALONE, EXPERT])}
    table = table.sort_values("method", key=lambda c: c.map(order)).reset_index(drop=True)
    beyond = pd.Series(crossed(episodes), index=episodes.index).groupby(episodes["method"]).sum()
    table["episodes_beyond"] = table["method"].map(beyond).astype(int)
    table["beyond_ucb95"] = [
        clopper_pearson_upper(int(k), int(n), 0.95)
        for k, n in zip(table["episodes_beyond"], table["n_episodes"], strict=True)
    ]
    if "deferred_share" in episodes:
        shares = episodes.groupby("method")["deferred_share"].mean()
        table["deferred_share"] = table["method"].map(shares)
    paired = final_paired(episodes, seed=seed)
    if len(paired):
        vs = paired[paired["vs"] == EXPERT].set_index("method")
        for col in PAIRED:
            table[col] = table["method"].map(vs[col])
    per_seed = episodes.groupby(["method", "train_seed"])["reward"].mean().unstack("train_seed")
    expert_per_seed = per_seed.loc[EXPERT] if EXPERT in per_seed.index else None
    main = RECOMMENDER if spec.handover is not None else AGENT_ALONE
    row = table[table["method"] == main].iloc[0]
    mine = episodes[episodes["method"] == main]
    certificate: dict[str, Any] = {
        "method": main,
        "episodes": int(row["n_episodes"]),
        "train_seeds": sorted(int(s) for s in episodes["train_seed"].unique()),
        "tracks_per_seed": int(mine.groupby("train_seed").size().max()),
        "block": int(seed),
        "episodes_beyond": int(row["episodes_beyond"]),
        "beyond_ucb95": float(row["beyond_ucb95"]),
        "reward": float(row["reward"]),
        "d_reward_vs_expert": [float(row.get(c, np.nan)) for c in PAIRED],
        "deferred_share": float(row.get("deferred_share", 0.0) or 0.0),
        "seeds_above_expert": None
        if expert_per_seed is None
        else int((per_seed.loc[main] > expert_per_seed).sum()),
    }
    goal_deferred = spec.deferred_share_limit if spec.deferred_share_limit < 1 else GOAL_DEFERRED
    certificate["goals"] = {
        "no_crossing": certificate["episodes_beyond"] == 0,
        f"bound_at_most_{GOAL_BOUND:g}": certificate["beyond_ucb95"] <= GOAL_BOUND,
        "not_reliably_below_expert": bool(certificate["d_reward_vs_expert"][2] >= 0),
        f"deferred_below_{goal_deferred:g}": certificate["deferred_share"] < goal_deferred,
    }
    return table, per_seed.reset_index(), certificate


def certificate_line(certificate: Mapping[str, Any]) -> str:
    """The certificate in one line, with its bound and what the reward interval supports."""
    d, lo, hi = certificate["d_reward_vs_expert"]
    verdict = (
        "reliably above the expert"
        if lo > 0
        else "reliably below the expert"
        if hi < 0
        else "no reliable reward difference from the expert"
    )
    return (
        f"certified on {certificate['episodes']} fresh episodes ({len(certificate['train_seeds'])}"
        f" training seeds x {certificate['tracks_per_seed']} held-out episodes of block "
        f"{certificate['block']}): {certificate['episodes_beyond']} beyond d_s (at most "
        f"{100 * certificate['beyond_ucb95']:.1f}% of episodes, 95% one-sided bound); reward "
        f"{d:+.1f} [{lo:+.1f}, {hi:+.1f}] against the expert ({verdict}); "
        f"{100 * certificate['deferred_share']:.1f}% of steps handed over (the handover acted)"
    )
