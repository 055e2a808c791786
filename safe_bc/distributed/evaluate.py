"""Parallel evaluation of policies on held-out seeds with persistent Ray actors.

Each policy's weights are put in the object store once (``ray.put``); actors keep
the policy they built last, so an actor that evaluates several episodes of the
same policy builds it once. With ``workers=0`` everything runs in this process and Ray is
not imported (a machine without Ray can still evaluate).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
import pandas as pd

from safe_bc.distributed.runtime import cpus_per_actor, ensure_ray
from safe_bc.metrics import summarize_policies
from safe_bc.policy import LockstepForward, Policy
from safe_bc.progress import progress_bar
from safe_bc.rollout.evaluate import EvalConfig, evaluate_episodes
from safe_bc.tasks import make_env
from safe_bc.tasks.env_config import EnvConfig

PolicySource = Any
"""Anything with ``build() -> Policy`` that pickles (``ExpertSource``, ``NetSource``)."""


class _Evaluator:
    """``n_envs`` envs and the last policy built; used in-process or inside an actor."""

    def __init__(self, env_config: EnvConfig, n_envs: int = 1) -> None:
        self.envs: list[gym.Env] = [make_env(env_config) for _ in range(n_envs)]
        self.key: str | None = None
        self.policy: Policy | None = None

    def run(
        self,
        key: str,
        source: PolicySource | list[Any],
        seeds: tuple[int, ...],
        thresholds: np.ndarray | None,
        eps: float,
        max_steps: int | None,
        combine: str = "any",
        lockstep_forward: LockstepForward = "rows",
    ) -> list[tuple[dict[str, float], dict[str, np.ndarray]]]:
        if key != self.key:
            if isinstance(source, list):  # boxed ObjectRef: fetched only when needed
                import ray

                source = ray.get(source[0])
            self.key, self.policy = key, source.build()
        return evaluate_episodes(
            self.envs,
            self.policy,
            seeds,
            thresholds=thresholds,
            eps=eps,
            max_steps=max_steps,
            combine=combine,  # type: ignore[arg-type]
            lockstep_forward=lockstep_forward,
        )

    def close(self) -> None:
        for env in self.envs:
            env.close()


LOCKSTEP_ENVS = 4
"""``envs_per_worker`` where each worker gets many episodes of one policy (Table 1, the
study's final phase, the improvement stage's test tracks): in the ``rows`` forward the same
rows as one env, in the default ``batched`` one the same rows for any number of workers
(tests/distributed/test_evaluate.py). Inference is about a quarter of a step: ``make bench``'s
eval case measures the gain ("BC net, 4 envs in lockstep"). A study's trials use their own
``StudySpec.trial_envs``."""


def evaluate_policies(
    sources: Mapping[str, PolicySource],
    config: EvalConfig,
    *,
    thresholds: np.ndarray | None = None,
    progress: bool = True,
    actor_cpus: float | None = None,
    envs_per_worker: int = 1,
    seeds: Sequence[int] | None = None,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Evaluate every policy on the same ``config.episodes`` held-out seeds (or on ``seeds``,
    e.g. the improvement runs' validation patients, when given).

    ``actor_cpus`` is each actor's CPU reservation; ``None`` shares the cluster's CPUs out
    (at most 1 each). Inside a Tune trial pass the size of the trial's worker bundles: actors
    asking for more than the trial reserved wait forever. ``envs_per_worker`` > 1: each
    worker (or this process) steps that many episodes of a BC policy in lockstep with one
    ``act_slots`` call per step (:func:`safe_bc.rollout.evaluate.evaluate_episodes`): with
    ``config.lockstep_forward="rows"`` the same rows as 1 on any CPU; with ``"batched"`` (the
    default) one forward pass over the envs, faster, the same rows again only for the same
    ``envs_per_worker`` on the same machine type (:attr:`EvalConfig.lockstep_forward`).

    Returns:
        ``(episodes, steps)``: one row per (policy, episode) with the metrics of
        :func:`safe_bc.metrics.episode_metrics`, and one row per step with the
        safety trace; both keyed by ``policy`` and ``env_seed``.
    """
    if envs_per_worker < 1:
        raise ValueError(f"envs_per_worker must be >= 1, got {envs_per_worker}")
    seeds = config.seeds() if seeds is None else list(seeds)
    chunks = [tuple(seeds[i : i + envs_per_worker]) for i in range(0, len(seeds), envs_per_worker)]
    tasks = [(key, chunk) for key in sources for chunk in chunks]
    ep_rows: list[dict[str, Any]] = []
    traces: list[pd.DataFrame] = []
    bar = progress_bar(show=progress, total=len(sources) * len(seeds), desc="evaluate", unit="ep")

    def record(task: tuple[str, tuple[int, ...]], values: list[tuple[dict, dict]]) -> None:
        for seed, value in zip(task[1], values, strict=True):
            record_one(task[0], seed, value)

    def record_one(key: str, seed: int, value: tuple[dict, dict]) -> None:
        metrics, trace = value
        ep_rows.append({"policy": key, "env_seed": seed, **metrics})
        frame = pd.DataFrame(trace)
        frame.insert(0, "env_seed", seed)
        frame.insert(0, "policy", key)
        traces.append(frame)
        bar.update(1)
        bar.set_postfix(
            reward=f"{metrics['reward']:.0f}",
            safety=f"{metrics['safety_mean']:.1f}",
            violations=metrics["violation_steps"],
        )

    args = (thresholds, config.eps, config.max_steps, config.combine, config.lockstep_forward)
    with bar:
        if config.workers == 0:
            local = _Evaluator(config.env, envs_per_worker)
            for task in tasks:
                record(task, local.run(task[0], sources[task[0]], task[1], *args))
            local.close()
        else:
            import ray

            from safe_bc.distributed.pool import run_on_actors

            ensure_ray()
            refs = {key: [ray.put(src)] for key, src in sources.items()}
            n = min(config.workers, len(tasks))
            cpus = cpus_per_actor(n) if actor_cpus is None else actor_cpus
            actor_cls = ray.remote(_Evaluator).options(num_cpus=cpus, max_restarts=0)
            run_on_actors(
                lambda: actor_cls.remote(config.env, envs_per_worker),
                n,
                tasks,
                lambda actor, t: actor.run.remote(t[0], refs[t[0]], t[1], *args),
                record,
            )
    order = {key: i for i, key in enumerate(sources)}
    episodes = pd.DataFrame(ep_rows)
    episodes = episodes.sort_values(
        ["policy", "env_seed"], key=lambda c: c.map(order) if c.name == "policy" else c
    ).reset_index(drop=True)
    steps = pd.concat(traces, ignore_index=True) if traces else pd.DataFrame()
    return episodes, steps


@dataclass(frozen=True)
class Evaluation:
    """Held-out evaluation of a set of policies (the output of :func:`evaluate`)."""

    episodes: pd.DataFrame
    """One row per (policy, episode): ``policy``, ``env_seed`` and the metrics of
    :data:`safe_bc.metrics.METRICS` (plus per-dimension safety statistics)."""
    steps: pd.DataFrame
    """One row per step: the safety trace (``safety``, ``critical``, ``violation``, ...)."""
    summary: pd.DataFrame
    """One row per policy: :func:`safe_bc.metrics.summarize_policies` (means over episodes,
    bootstrap CIs over episodes, ``episodes_with_violation``)."""


def evaluate(
    sources: Mapping[str, PolicySource],
    config: EvalConfig,
    limits: np.ndarray | None,
    *,
    progress: bool = True,
    actor_cpus: float | None = None,
    envs_per_worker: int = 1,
) -> Evaluation:
    """The one evaluation path: every policy on the same held-out seeds, summarised with the
    one metric list. ``limits`` are the demonstrations' ``d_s`` (worst expert cost per
    dimension) that define violations and the critical zone.

    The expert (``safe-bc expert``), a trained agent (``safe-bc evaluate``) and Table 1 call
    this (Table 1 then regroups the same per-episode rows by method with its crossed
    bootstrap); a study's trials and final phase make their own metrics from the rows and call
    :func:`evaluate_policies`, skipping the summary's bootstrap.
    """
    episodes, steps = evaluate_policies(
        sources,
        config,
        thresholds=limits,
        progress=progress,
        actor_cpus=actor_cpus,
        envs_per_worker=envs_per_worker,
    )
    summary = summarize_policies(episodes, ["policy"], seed=config.seed)
    order = {key: i for i, key in enumerate(sources)}
    summary = summary.sort_values("policy", key=lambda c: c.map(order)).reset_index(drop=True)
    return Evaluation(episodes, steps, summary)
