"""One study trial on Ray Tune: select, train, checkpoint, then evaluate in rounds.

A trial trains once (the first report carries the weights as a checkpoint, so a retry or a
resumed study never retrains: :func:`resume_point`), is screened on the first
``screen_episodes`` held-out tracks (successive halving may stop it there) and, if it
survives, evaluated on the rest of its ``eval_episodes`` tracks. Every report carries every
key of ``TRIAL_METRICS``.

With an improvement stage (``StudySpec.improve``), the trained net is improved by constrained
RL (:func:`safe_bc.improve.improve_from_net`, in the trial's folder, resumable) between the
training and the evaluation, and the improved agent is what the rounds evaluate.
"""

from __future__ import annotations

import math
import random
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch
from ray import tune

from safe_bc.bc import CheckpointError, load_checkpoint, read_checkpoint_meta
from safe_bc.bc.net import BCNet
from safe_bc.bc.train import training_threads
from safe_bc.data.store import load_demonstrations
from safe_bc.demos import Demonstrations
from safe_bc.distributed.evaluate import evaluate
from safe_bc.distributed.search import ROUND, SCORE, screen_score
from safe_bc.evaluation import EvalConfig, NetSource
from safe_bc.experiment import RunConfig, train_run
from safe_bc.metrics import mean_metrics
from safe_bc.selection import SelectionError
from safe_bc.study import TRIAL_METRICS, Limits, StudySpec, constraints
from safe_bc.tasks import Bounds, dataset_action_bounds


@dataclass(frozen=True)
class TrialJob:
    """What every trial of a study shares (pickled into the trainable; small)."""

    spec: StudySpec
    """The study."""
    demos: str
    """Absolute path of the demonstration set (trials run in their own folders)."""
    limits: Limits
    """The constraints' thresholds and tolerance (from the expert's demonstrations)."""
    cost_limits: tuple[float, ...]
    """The demonstrations' ``d_s`` (max cost per dimension): violations and critical share."""

    @property
    def threshold(self) -> float:
        """The safety-mean threshold."""
        return self.limits.threshold


_DEMOS: dict[str, Demonstrations] = {}
"""Per-process cache: ``reuse_actors=True`` keeps trial processes, so demos load once."""


def bounds_for(demos: str | Path) -> Bounds:
    """The action bounds of the demonstration set at ``demos`` (its ``dataset.json``, else
    its task's entry in :mod:`safe_bc.tasks`)."""
    return dataset_action_bounds(demos)


def cached_demos(path: str) -> Demonstrations:
    """The demonstration set at ``path``, loaded once per process."""
    if path not in _DEMOS:
        _DEMOS.clear()
        _DEMOS[path] = load_demonstrations(Path(path))
    return _DEMOS[path]


def trial_threads(spec: StudySpec) -> int:
    """Torch threads every trial of ``spec`` trains with: ``base.bc.train.num_threads``, else 1.

    Never the CPU reservation (``cpus_per_trial``; Ray also sets ``OMP_NUM_THREADS`` from it)
    nor the reused process's setting: 1 and 2 threads give different weights, so the count is
    part of the trial's run config (recorded in its checkpoint) and a rerun with other
    resources, or ``train_run`` of that config in any process, gives the same weights.
    """
    return training_threads(spec.base.bc.train)


def reset_trial_state(seed: int) -> None:
    """Reset the global random state a reused trial process carries over."""
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def eval_rounds(spec: StudySpec) -> list[tuple[int, int]]:
    """``(first_episode, episodes)`` of each evaluation round: the screening, then the rest.

    >>> from safe_bc.study import Float
    >>> eval_rounds(StudySpec("s", {"selection.alpha": Float(0, 1)}))
    [(0, 3), (3, 7)]
    """
    if spec.screens:
        first = spec.screen_episodes
        return [(0, first), (first, spec.eval_episodes - first)]
    return [(0, spec.eval_episodes)]


def blank_metrics(job: TrialJob) -> dict[str, Any]:
    """A report with every key of ``TRIAL_METRICS`` (NaN where not known yet)."""
    spec = job.spec
    seeds = EvalConfig(episodes=spec.eval_episodes, seed=spec.eval_seed).seeds()
    out: dict[str, Any] = {k: math.nan for k in TRIAL_METRICS}
    out.update(
        threshold=job.threshold,
        feasible=False,
        train_seed=spec.base.bc.train.seed,
        eval_seed=spec.eval_seed,
        eval_seeds=",".join(str(s) for s in seeds),
        episodes=0,
        resumed=False,
        phase="",
        error="",
    )
    out[ROUND] = 0  # ASHA reads these on every report: round 0 is before any evaluation
    out[SCORE] = math.nan
    return out


def evaluate_net(
    model: BCNet, run_cfg: RunConfig, job: TrialJob, first: int, n: int
) -> pd.DataFrame:
    """Held-out episodes ``first .. first + n - 1`` of the trial's seed block (one row each)."""
    return evaluate_source(NetSource.from_model(model, run_cfg.bc), run_cfg, job, first, n)


def evaluate_source(
    source: Any, run_cfg: RunConfig, job: TrialJob, first: int, n: int
) -> pd.DataFrame:
    """:func:`evaluate_net` for any policy source (e.g. an improved agent)."""
    spec = job.spec
    config = EvalConfig(
        episodes=n,
        first_episode=first,
        workers=spec.rollout_workers,
        seed=spec.eval_seed,
        env=spec.env,
        max_steps=spec.max_steps,
        eps=spec.critical_eps,
        combine=run_cfg.selection.combine,
    )
    result = evaluate(
        {"trial": source},
        config,
        np.asarray(job.cost_limits),
        progress=False,
        actor_cpus=spec.cpus_per_worker if spec.rollout_workers else None,
    )
    return result.episodes


def trial_values(episodes: pd.DataFrame, limits: Limits) -> dict[str, float]:
    """A trial's metrics from its evaluated episodes: the means of ``metrics.METRICS`` (the
    same definitions as every other table), the objective and the constraints."""
    means = mean_metrics(episodes)
    values = {k: v for k, v in means.items() if k not in ("reward", "steps")}
    values.update(
        reward_mean=means["reward"],
        reward_std=float(episodes["reward"].std(ddof=0)),
        steps_mean=means["steps"],
        episodes=len(episodes),
    )
    values.update(constraints(means, limits))
    return values


def _load(checkpoint: tune.Checkpoint) -> tuple[BCNet, dict[str, Any]]:
    with checkpoint.as_directory() as d:
        model, _ = load_checkpoint(d)
        return model, read_checkpoint_meta(d)["extra"]


def stored_checkpoint(fs: Any, folder: str) -> tuple[BCNet, dict[str, Any]] | None:
    """The newest complete checkpoint among the ``checkpoint_*`` folders of a trial's folder
    ``folder`` on the ``pyarrow`` filesystem ``fs``: its net and ``extra`` (``None``: none)."""
    import pyarrow.fs as pafs

    infos = fs.get_file_info(pafs.FileSelector(folder, allow_not_found=True))
    dirs = [
        i.path
        for i in infos
        if i.type == pafs.FileType.Directory and i.base_name.startswith("checkpoint_")
    ]
    for d in sorted(dirs, reverse=True):
        try:
            return _load(tune.Checkpoint(d, filesystem=fs))
        except (CheckpointError, OSError):  # cut short by a kill: try an older one
            continue
    return None


def resume_point() -> tuple[BCNet, dict[str, Any]] | None:
    """The trained net and its checkpoint's ``extra`` when this trial has trained before.

    Tune hands over the checkpoint it recorded (a retry, a resumed study). A checkpoint the
    trial reported just before the driver stopped (Ctrl-C, or killed) is on the storage but not
    in Tune's saved experiment state, and Tune then restarts the trial without one (Ray 2.60):
    the newest complete checkpoint in the trial's folder is used instead of retraining.
    """
    checkpoint = tune.get_checkpoint()
    if checkpoint is not None:
        return _load(checkpoint)
    storage = tune.get_context().get_storage()
    return stored_checkpoint(storage.storage_filesystem, storage.trial_fs_path)


def trial_folder() -> Path:
    """A folder of this trial that outlives retries and a resumed study: inside the trial's
    folder of the storage when that is local, else the trial's local folder."""
    import pyarrow.fs as pafs

    storage = tune.get_context().get_storage()
    if isinstance(storage.storage_filesystem, pafs.LocalFileSystem):
        return Path(storage.trial_fs_path)
    return Path(tune.get_context().get_trial_dir())


def improve_trial(
    model: BCNet, run_cfg: RunConfig, job: TrialJob, params: dict[str, Any], folder: Path
) -> tuple[Any, dict[str, float]]:
    """The trial's improvement stage: the improved agent and its report values."""
    from safe_bc.improve import improve_from_net

    spec = job.spec
    icfg = spec.improve_config(params, seed=run_cfg.bc.train.seed)
    assert icfg is not None
    source, result = improve_from_net(
        model, run_cfg.bc, run_cfg.selection, job.demos, spec.env.env_id, folder, icfg
    )
    return source, {
        "improve_seconds": float(result.history["seconds"].sum()),
        "improve_kept_iteration": float(result.kept_iteration),
    }


def run_trial(config: dict[str, Any], job: TrialJob) -> None:
    """One trial: train (or resume from its checkpoint), report, evaluate in rounds, report."""
    start = time.perf_counter()
    spec = job.spec
    seed = spec.base.bc.train.seed
    reset_trial_state(seed)
    threads = trial_threads(spec)
    torch.set_num_threads(threads)
    run_cfg = spec.run_config({k: config[k] for k in spec.params}, num_threads=threads)
    metrics = blank_metrics(job)

    resumed = resume_point()
    if resumed is not None:  # a retry or a resumed study: the weights are already trained
        model, extra = resumed
        metrics.update(extra["train"], resumed=True)
        earlier = float(extra["trained_s"])
    else:
        try:
            result, selection = train_run(
                cached_demos(job.demos), run_cfg, action_bounds=bounds_for(job.demos)
            )
        except SelectionError as e:  # a configuration the data cannot support: no retry
            metrics.update(phase="invalid", error=str(e), duration_s=time.perf_counter() - start)
            tune.report(metrics)
            return
        if not math.isfinite(result.final_loss):  # diverged: nothing to evaluate, no retry
            metrics.update(phase="invalid", error=f"training diverged (loss {result.final_loss})")
            metrics.update(duration_s=time.perf_counter() - start)
            tune.report(metrics)
            return
        model, earlier = result.model, 0.0
        train_info = {
            "train_loss": result.final_loss,
            "train_seconds": result.seconds,
            "n_critical": selection.n_critical,
            "critical_fraction": selection.n_critical / selection.n_valid,
        }
        trained_s = time.perf_counter() - start
        metrics.update(train_info, phase="trained", duration_s=trained_s)
        extra = {"train": train_info, "trained_s": trained_s, "run_config": run_cfg.to_dict()}
        with tempfile.TemporaryDirectory() as d:
            result.save(d, extra=extra)
            tune.report(metrics, checkpoint=tune.Checkpoint.from_directory(d))

    source: Any = NetSource.from_model(model, run_cfg.bc)
    if spec.improve is not None:  # its time counts in duration_s, not in eval_seconds
        params = {k: config[k] for k in spec.params}
        source, values = improve_trial(model, run_cfg, job, params, trial_folder() / "improve")
        metrics.update(values)

    rounds = eval_rounds(spec)
    parts: list[pd.DataFrame] = []
    eval_s = 0.0
    for i, (first, n) in enumerate(rounds, start=1):
        t0 = time.perf_counter()
        parts.append(evaluate_source(source, run_cfg, job, first, n))
        eval_s += time.perf_counter() - t0
        values = trial_values(pd.concat(parts, ignore_index=True), job.limits)
        metrics.update(
            values,
            phase="evaluated" if i == len(rounds) else "screened",
            eval_seconds=eval_s,
            duration_s=earlier + time.perf_counter() - start,
            feasible=bool(values["constraint"] <= 0),
        )
        metrics[ROUND] = i
        metrics[SCORE] = screen_score(values["reward_mean"], values["constraint"])
        tune.report(metrics)
