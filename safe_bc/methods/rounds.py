"""What the rounds of an interactive-training run share (critical-zone queries,
:mod:`safe_bc.methods.queries.run`; self-imitation, :mod:`safe_bc.methods.selfimprove.run`): the run
folder's
identity and done records, the retraining (:class:`TrainJob`, in this process or elsewhere)
and the training data (demonstrations plus each round's new rows). No Ray."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from safe_bc.bc.checkpoint import checkpoint_unit, load_checkpoint, save_checkpoint
from safe_bc.bc.net import BCNet
from safe_bc.data.atomic import write_json_atomic
from safe_bc.data.demos import Demonstrations
from safe_bc.data.provenance import repo_relative
from safe_bc.rollout.evaluate import NetSource
from safe_bc.run_config import RunConfig
from safe_bc.selection import Selection


@dataclass(frozen=True)
class TrainJob:
    """One retraining: the aggregate data, its selection and the BC settings."""

    demos: Demonstrations
    selection: Selection
    run_config: RunConfig
    action_bounds: tuple[Any, Any] | None = None
    curve: Path | None = None
    """Where :func:`train_local` writes the retraining's learning curve (``curve.parquet``
    and its TensorBoard events ``bc/*`` beside it); ``None``: nowhere. It changes no weight."""


ROUND_CURVE = Path("bc") / "curve.parquet"
"""A round's retraining curve, in the round's folder (a study's TensorBoard run shows it)."""

TrainFn = Callable[[TrainJob], NetSource]

Rollouts = Callable[[Any, Sequence[int]], list[Any]]
"""Runs a round's job on tracks, results in track order (``rollouts(job, seeds)``)."""
Parallel = Callable[[Rollouts, int], Rollouts]
"""Spreads rollouts over workers: ``parallel(rollouts, workers)`` gives the same results as
``rollouts``. The caller passes it in, so that this layer names no Ray: the study's trials,
the final phase and the CLI pass :class:`safe_bc.distributed.rollouts.ChunkedRayRollouts`."""


def spread(rollouts: Rollouts, workers: int, parallel: Parallel | None) -> Rollouts:
    """``rollouts`` on ``workers`` workers by ``parallel``.

    Raises:
        ValueError: ``parallel`` is ``None`` (one line: ``workers`` 0 runs in this process).
    """
    if parallel is None:
        raise ValueError(
            f"workers={workers} needs a parallel rollout factory (the caller's parallel, "
            "e.g. safe_bc.distributed.rollouts.ChunkedRayRollouts); workers=0 runs in this process"
        )
    return parallel(rollouts, workers)


def train_local(job: TrainJob) -> NetSource:
    """Train the job's BC net in this process (``train_bc``: bit-identical for the same job)."""
    from safe_bc.bc.train import train_bc

    cfg = job.run_config
    sampler = job.selection.sampler(
        cfg.bc.train.batch_size, np.random.default_rng(cfg.bc.train.seed)
    )
    result = train_bc(
        job.demos,
        sampler,
        cfg.bc.network,
        cfg.bc.preprocess,
        cfg.bc.train,
        action_bounds=job.action_bounds,
    )
    if job.curve is not None:
        from safe_bc.data.curves import write_curve

        write_curve(job.curve, result.curve(), "batch", "bc")
    return NetSource.from_model(result.model, result.config)


def with_batches(run_config: RunConfig, batches: int | None) -> RunConfig:
    """``run_config`` with ``batches`` BC batches (``None``: unchanged): the retraining's."""
    if batches is None:
        return run_config
    train = replace(run_config.bc.train, batches=batches)
    return replace(run_config, bc=replace(run_config.bc, train=train))


def net_model(source: NetSource) -> BCNet:
    """The net of ``source`` (eval mode)."""
    from safe_bc.bc.config import BCConfig
    from safe_bc.bc.net import ModelSpec

    cfg = BCConfig.from_dict(source.config)
    model = BCNet(ModelSpec.from_dict(source.spec), cfg.preprocess, cfg.network)
    model.load_state_dict(source.state)
    return model.eval()


def save_round_net(
    path: Path,
    source: NetSource,
    bc: Any,
    method: str,
    identity: Mapping[str, Any],
    round_: int,
    env_config: Any,
    demos_path: Any,
) -> None:
    """Save round ``round_``'s retrained net at ``path`` (atomically, checksummed), recording
    the run's ``identity`` under ``method`` with the round, the env id and the demonstrations."""
    with checkpoint_unit(path) as unit:
        save_checkpoint(
            unit, net_model(source), bc,
            extra={
                method: {**identity, "round": round_},
                "env_id": getattr(env_config, "env_id", None),
                "demos": repo_relative(demos_path),
            },
        )  # fmt: skip


def policy_source(policy: Path) -> NetSource:
    """A round's (or the start's) written net."""
    model, cfg = load_checkpoint(policy)
    return NetSource.from_model(model, cfg)


def weights_digest(state: Mapping[str, Any]) -> str:
    """SHA-256 of a net's weights (a ``state_dict``: its order, raw bytes)."""
    h = hashlib.sha256()
    for name, tensor in state.items():
        h.update(name.encode())
        h.update(tensor.detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()


def read_json(path: Path) -> dict[str, Any] | None:
    """The JSON record at ``path`` (``None``: not written)."""
    return json.loads(path.read_text()) if path.is_file() else None


def check_identity(path: Path, identity: dict[str, Any], run: str, config: str) -> None:
    """Write the run folder's ``identity`` to ``path`` (``identity.json``) or check that the
    one there is the same; another raises ``ValueError`` ("belongs to another ``run``")."""
    found = read_json(path)
    want = json.loads(json.dumps(identity))
    if found is None:
        write_json_atomic(path, want)
    elif found != want:
        raise ValueError(
            f"{path.parent} belongs to another {run} (start, run config, demonstrations or "
            f"{config} differ); use another folder"
        )


class RowPiece(Protocol):
    """Rows one round adds to the training data (a queried episode, a kept piece)."""

    seed: int
    steps: np.ndarray
    observations: np.ndarray
    actions: np.ndarray
    costs: np.ndarray


def aggregate_rows(
    demos: Demonstrations,
    pieces: Sequence[RowPiece],
    trained: Sequence[np.ndarray],
    observations: Any = None,
) -> tuple[Demonstrations, np.ndarray]:
    """Demonstrations followed by the pieces' rows, and ``(N,) bool`` the rows trained on
    (``trained[i]``: piece ``i``'s).

    Each piece gets its own episode id after the demonstrations'; its other rows (context:
    frames only stacked, never trained on) are marked as warm-up (not scored). New rows have
    no safety distances (``NaN``; training does not read them). ``observations``: the
    aggregate's frames already laid out in that order (a :class:`~safe_bc.data.frames.FrameFile`
    written from the demonstrations and the pieces with data, say), used instead of
    concatenating the pieces' own (which may then be empty placeholders).
    """
    parts = [(p, m) for p, m in zip(pieces, trained, strict=True) if len(p.steps)]
    if not parts:
        return demos, np.zeros(len(demos), bool)
    first_id = int(demos.episode_ids.max()) + 1 if len(demos) else 0
    n_new = sum(len(p.steps) for p, _ in parts)
    s = demos.costs.shape[1]
    if observations is None:
        observations = np.concatenate([demos.observations, *[p.observations for p, _ in parts]])
    elif len(observations) != len(demos) + n_new:
        raise ValueError(
            f"observations hold {len(observations)} rows, the aggregate {len(demos) + n_new}"
        )
    agg = Demonstrations(
        observations=observations,
        actions=np.concatenate([demos.actions, *[p.actions for p, _ in parts]]).astype(np.float32),
        costs=np.concatenate([demos.costs, *[p.costs for p, _ in parts]]).astype(np.float32),
        safety=np.concatenate([demos.safety, np.full((n_new, s), np.nan, np.float32)]),
        episode_ids=np.concatenate(
            [
                demos.episode_ids,
                *[np.full(len(p.steps), first_id + i, np.int64) for i, (p, _) in enumerate(parts)],
            ]
        ),
        steps=np.concatenate([demos.steps, *[p.steps.astype(np.int64) for p, _ in parts]]),
        seeds=np.concatenate(
            [demos.seeds, *[np.full(len(p.steps), p.seed, np.int64) for p, _ in parts]]
        ),
        warmup=np.concatenate([demos.warmup, *[~m for _, m in parts]]),
        safety_dims=demos.safety_dims,
    )
    mask = np.concatenate([np.zeros(len(demos), bool), *[m for _, m in parts]])
    return agg, mask
