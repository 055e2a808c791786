"""Behaviour cloning: regress the expert's actions on alpha-mixed batches (cleanrl style)."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch

from safe_bc.bc.checkpoint import save_checkpoint
from safe_bc.bc.config import BCConfig, NetworkConfig, PreprocessConfig, TrainConfig
from safe_bc.bc.net import BCNet, ModelSpec
from safe_bc.bc.policy import BCPolicy
from safe_bc.bc.preprocess import (
    frame_shape,
    frame_stack_index,
    gather_inputs,
    preprocess,
    stack,
    standardization_stats,
)
from safe_bc.data.demos import Demonstrations
from safe_bc.progress import progress_bar
from safe_bc.selection import BatchSampler, Selection, warn_if_improper_subset

LogFn = Callable[[int, dict[str, float]], None]
"""``log_fn(batch, metrics)``: called every ``log_every`` batches with ``loss`` (mean since
the previous call), ``samples_per_s`` and, with a validation set, ``val_loss``."""


CACHE_LIMIT_BYTES = 2**30
"""Largest preprocessed-frame cache ``train_bc`` keeps (1 GiB); bigger datasets are
preprocessed per batch (the same values, more work)."""


class BatchBuilder:
    """Gathers ``(inputs, targets)`` tensors for row indices of in-memory demonstrations.

    With ``cache_chunk`` set, each frame is preprocessed once, on first use, and kept: the
    frames a batch needs come from a ``(N, *frame_shape) float32`` cache filled by
    preprocessing calls of exactly ``cache_chunk`` frames (missing rows first, topped up with
    other rows not yet cached, padded by repetition when fewer remain). Give it the number of
    frames one uncached batch preprocesses (``batch_size * frame_stack``): every preprocessing
    call then has the shape of that batch's, so the cached values are bit for bit the ones the
    per-batch path computes (torch's CPU kernels for the grayscale matmul may differ between
    call shapes, not between rows of one call). Without it every batch is preprocessed anew.
    ``reuse_output`` (with ``cache_chunk``): ``inputs`` gathers into one reused tensor, which
    the next call overwrites (a fresh 2 MB tensor per batch costs as much again in page
    faults); for a loop that is done with a batch before it asks for the next.
    """

    def __init__(
        self,
        demos: Demonstrations,
        pre_cfg: PreprocessConfig,
        cache_chunk: int | None = None,
        reuse_output: bool = False,
    ) -> None:
        self.observations = demos.observations
        self.actions = torch.tensor(np.asarray(demos.actions, np.float32))  # own copy
        self.pre_cfg = pre_cfg
        self.stack_index = (
            frame_stack_index(demos.episode_ids, demos.steps, pre_cfg.frame_stack)
            if pre_cfg.frame_stack > 1
            else None
        )
        if cache_chunk is not None and cache_chunk < 1:
            raise ValueError(f"cache_chunk must be >= 1, got {cache_chunk}")
        self.cache_chunk = cache_chunk
        self._frames: torch.Tensor | None = None  # (N, *frame_shape) preprocessed, lazily
        self._cached = np.zeros(len(self.observations), bool)
        self._stride: tuple[int, ...] | None = None  # preprocess()'s output strides
        self.reuse_output = reuse_output
        self._out: torch.Tensor | None = None  # the reused gather target

    @staticmethod
    def cache_bytes(demos: Demonstrations, pre_cfg: PreprocessConfig) -> int:
        """Size of the full preprocessed-frame cache for ``demos``."""
        shape = frame_shape(demos.observations.shape[1:], pre_cfg)
        return 4 * len(demos.observations) * int(np.prod(shape))

    def inputs(self, rows: np.ndarray) -> torch.Tensor:
        """``rows (B,) -> (B, *input_shape) float32``."""
        if self.cache_chunk is None:
            return gather_inputs(self.observations, rows, self.pre_cfg, self.stack_index)
        k = self.pre_cfg.frame_stack
        x = self._cached_frames(self._frame_rows(rows))
        return x if k == 1 else stack(x, k)

    def prefill(self, rows: np.ndarray) -> None:
        """Preprocess the frames that ``rows (B,)`` need into the cache now (with ``cache_chunk``;
        a no-op without): the same values as filling them on first use, so a training loop can
        keep preprocessing out of its timed batches."""
        if self.cache_chunk is not None:
            self._ensure_cached(self._frame_rows(rows))

    def _frame_rows(self, rows: np.ndarray) -> np.ndarray:
        """The frame rows that samples ``rows (B,)`` stack, oldest first: ``(B * k,)``."""
        rows = np.asarray(rows, np.int64)
        return rows if self.stack_index is None else self.stack_index[rows].reshape(-1)

    def _ensure_cached(self, idx: np.ndarray) -> None:
        """Preprocess the frames of rows ``idx`` that the cache does not hold yet."""
        missing = idx[~self._cached[idx]]
        if missing.size:
            self._fill(np.unique(missing))

    def targets(self, rows: np.ndarray) -> torch.Tensor:
        """``rows (B,) -> (B, A) float32`` expert actions."""
        return self.actions[torch.as_tensor(rows)]

    def _cached_frames(self, idx: np.ndarray) -> torch.Tensor:
        """Preprocessed frames of rows ``idx (M,)``, filling the cache where needed."""
        self._ensure_cached(idx)
        assert self._frames is not None and self._stride is not None
        index = torch.from_numpy(idx)
        if self.reuse_output:
            shape = (len(idx), *self._frames.shape[1:])
            if self._out is None or self._out.shape != shape:
                self._out = torch.empty(shape, dtype=self._frames.dtype)
            x = torch.index_select(self._frames, 0, index, out=self._out)
        else:
            x = self._frames[index]
        # the per-batch path's strides: a grayscale frame's (B, 1, H, W) tensor comes out of
        # preprocess() with a channel stride of 1, and the conv layers pick their kernels (and
        # so their rounding) by strides. Strides of size-1 dims address nothing: same memory.
        if x.stride() != self._stride:
            dims = zip(x.stride(), self._stride, x.shape, strict=True)
            if all(a == b or n == 1 for a, b, n in dims):
                x = x.as_strided(x.shape, self._stride)
            else:  # not seen: preprocess() outputs are dense, batch-major
                x = torch.empty_strided(x.shape, self._stride).copy_(x)
        return x

    def _fill(self, missing: np.ndarray) -> None:
        """Preprocess the rows ``missing`` (sorted, unique) into the cache."""
        chunk = self.cache_chunk
        assert chunk is not None
        n = len(self.observations)
        while missing.size:
            rows, missing = missing[:chunk], missing[chunk:]
            if len(rows) < chunk:  # top up with uncached rows (any order: rows are independent)
                free = np.flatnonzero(~self._cached)
                free = free[~np.isin(free, rows)][: chunk - len(rows)]
                rows = np.concatenate([rows, free])
            real = len(rows)
            if real < chunk:  # fewer than a chunk of rows left at all: pad by repetition
                rows = np.resize(rows, chunk)
            x = preprocess(self.observations[rows], self.pre_cfg)
            if self._frames is None:
                self._frames = torch.empty((n, *x.shape[1:]), dtype=x.dtype)
                self._stride = x.stride()
            self._frames[torch.from_numpy(rows[:real])] = x[:real]
            self._cached[rows[:real]] = True


@dataclass(frozen=True, eq=False)
class TrainResult:
    """Outcome of ``train_bc``.

    Attributes:
        model: the trained net, in eval mode.
        config: the preprocessing, network and training configs used.
        log_steps: ``(K,) int64`` batch number (1-based) of each log point.
        losses: ``(K,) float64`` mean training loss over the batches since the previous log.
        seconds: wall time of the training loop (validation excluded).
        samples_per_s: ``batches * batch_size / seconds``.
        prepare_seconds: wall time spent before the loop preprocessing the frames the sampler
            can draw into the frame cache (0 when the dataset is too big to cache).
    """

    model: BCNet
    config: BCConfig
    log_steps: np.ndarray
    losses: np.ndarray
    seconds: float
    samples_per_s: float
    prepare_seconds: float = 0.0
    val_losses: np.ndarray | None = None
    """``(K,) float64`` loss on the validation set at each log point (``None``: trained
    without one)."""
    log_seconds: np.ndarray | None = None
    """``(K,) float64`` wall time of the loop at each log point (validation excluded)."""
    val_seconds: float = 0.0
    """Wall time of the validation passes at the log points, added up (0 without a
    validation set): what the validation loss cost on top of :attr:`seconds`."""

    @property
    def final_loss(self) -> float:
        return float(self.losses[-1])

    def curve(self) -> pd.DataFrame:
        """The learning curve, one row per log point: ``batch``, ``train_loss`` (mean over
        the batches since the previous row), ``val_loss`` (NaN without a validation set),
        ``samples`` (trained so far), ``seconds`` (the loop's wall time so far, NaN when not
        recorded)."""
        k = len(self.log_steps)
        nan = np.full(k, np.nan)
        return pd.DataFrame(
            {
                "batch": self.log_steps.astype(np.int64),
                "train_loss": self.losses.astype(np.float64),
                "val_loss": nan if self.val_losses is None else self.val_losses,
                "samples": self.log_steps.astype(np.int64) * self.config.train.batch_size,
                "seconds": nan if self.log_seconds is None else self.log_seconds,
            }
        )

    def policy(self) -> BCPolicy:
        """The trained net as a ``Policy``."""
        return BCPolicy(self.model, self.config.preprocess)

    def summary(self) -> dict[str, Any]:
        """JSON-able summary (configs, loss curve, throughput)."""
        return {
            "config": self.config.to_dict(),
            "spec": self.model.spec.to_dict(),
            "log_steps": self.log_steps.tolist(),
            "losses": self.losses.tolist(),
            "final_loss": self.final_loss,
            "seconds": self.seconds,
            "samples_per_s": self.samples_per_s,
            "prepare_seconds": self.prepare_seconds,
            **({} if self.val_losses is None else {"val_losses": self.val_losses.tolist()}),
        }

    def save(self, directory: str | Path, extra: dict[str, Any] | None = None) -> Path:
        """``save_checkpoint(directory, model, config, extra)``."""
        return save_checkpoint(directory, self.model, self.config, extra)


DEFAULT_NUM_THREADS = 1
"""Torch threads of a training run whose ``TrainConfig.num_threads`` is ``None``. Fixed rather
than the process's setting: the thread count changes how float sums are split, so 1 and 2
threads give different weights, and the process's count depends on the machine,
``OMP_NUM_THREADS`` (Ray sets it from a task's CPU reservation) and earlier
``torch.set_num_threads`` calls (a reused Tune trial process)."""


def training_threads(train_cfg: TrainConfig) -> int:
    """The torch threads ``train_bc`` uses for ``train_cfg``: its ``num_threads``, else
    ``DEFAULT_NUM_THREADS``."""
    return DEFAULT_NUM_THREADS if train_cfg.num_threads is None else train_cfg.num_threads


@contextmanager
def torch_settings(num_threads: int | None) -> Iterator[None]:
    """Deterministic algorithms, optional thread count and a forked torch RNG, all restored
    on exit so that training does not leak global state into the caller. The first call in a
    process pays a one-off ~2-5 s (``torch.use_deterministic_algorithms`` imports
    ``torch._inductor``)."""
    old_det = torch.are_deterministic_algorithms_enabled()
    old_warn = torch.is_deterministic_algorithms_warn_only_enabled()
    old_threads = torch.get_num_threads()
    try:
        torch.use_deterministic_algorithms(True)
        if num_threads is not None:
            torch.set_num_threads(num_threads)
        with torch.random.fork_rng(devices=[]):
            yield
    finally:
        torch.use_deterministic_algorithms(old_det, warn_only=old_warn)
        if num_threads is not None:
            torch.set_num_threads(old_threads)


def sampler_for(selection: Selection, train_cfg: TrainConfig) -> BatchSampler:
    """The selection's sampler with the config's batch size and seed: the alpha mix
    (``MixedBatchSampler``) or, for the BC-Safe and cost-weighted baselines
    (``SelectionConfig.mode``), a ``WeightedBatchSampler``. Warns
    (``CriticalSubsetWarning``) when the mix's ``T_eps`` holds none or all of the scored
    rows while ``alpha > 0``: then the mix has no effect."""
    warn_if_improper_subset(selection)
    return selection.sampler(train_cfg.batch_size, np.random.default_rng(train_cfg.seed))


def loss_weights(train_cfg: TrainConfig, n_actions: int) -> torch.Tensor:
    """The per-action weights of the squared error, summing to 1: ``train_cfg.loss_weights``
    normalised, else equal.

    Raises:
        ValueError: ``loss_weights`` has not one weight per action dimension.
    """
    weights = torch.ones(n_actions)
    if train_cfg.loss_weights is not None:
        if len(train_cfg.loss_weights) != n_actions:
            raise ValueError(
                f"{len(train_cfg.loss_weights)} loss_weights for {n_actions} action dimensions"
            )
        weights = torch.tensor(train_cfg.loss_weights, dtype=torch.float32)
    return weights / weights.sum()


def train_bc(
    demos: Demonstrations,
    sampler: BatchSampler,
    net_cfg: NetworkConfig,
    pre_cfg: PreprocessConfig,
    train_cfg: TrainConfig,
    progress: bool = False,
    log_fn: LogFn | None = None,
    action_bounds: tuple[Sequence[float], Sequence[float]] | None = None,
    validation: Demonstrations | None = None,
) -> TrainResult:
    """Train a ``BCNet`` for ``train_cfg.batches`` Adam steps on MSE to the expert's actions.

    Batches are the sampler's row indices, drawn from a copy of the sampler whose random
    stream starts from ``train_cfg.seed`` (the passed sampler is not advanced); only those
    rows are preprocessed. The weights are a function of the data and the configs alone,
    bit for bit: the thread count is ``training_threads(train_cfg)`` (``DEFAULT_NUM_THREADS``
    when unset, recorded in the result's config), never the process's. Torch's global state
    is restored on return (``torch_settings``: a one-off ~2-5 s on a process's first call).

    Args:
        demos: ``N`` state-action pairs (frames or vectors).
        sampler: batch sampler over the ``N`` rows (``MixedBatchSampler`` or
            ``WeightedBatchSampler``, see ``sampler_for``); its ``batch_size`` must equal
            ``train_cfg.batch_size``.
        net_cfg, pre_cfg, train_cfg: hyper-parameters.
        progress: show a tqdm bar with the loss and samples/s.
        log_fn: called at each log point (see ``LogFn``).
        action_bounds: ``(low (A,), high (A,))``; default from ``ModelSpec.for_data``.
        validation: held-out demonstrations: at each log point the loss (the training loss's
            weighted squared error) over their scored rows, in eval mode without gradients.
            It reads no random numbers and changes no weight: the training is the same with
            or without it.
    """
    _check_sampler(sampler, len(demos), train_cfg.batch_size)
    n_actions = demos.actions.shape[1]
    weights = loss_weights(train_cfg, n_actions)
    train_cfg = replace(train_cfg, num_threads=training_threads(train_cfg))  # recorded
    spec = ModelSpec.for_data(demos.observations.shape[1:], n_actions, action_bounds)
    # frames preprocessed once each, in calls shaped like one batch's (same values, see
    # BatchBuilder), before the timed loop: the rows the sampler can draw (rows outside
    # ``valid`` that a batch still asks for are filled on first use)
    chunk = train_cfg.batch_size * pre_cfg.frame_stack
    builder, prepare_seconds = _training_builder(demos, pre_cfg, chunk, sampler.valid)
    sampler = sampler.with_rng(np.random.default_rng(train_cfg.seed))
    log_steps: list[int] = []
    losses: list[float] = []
    val_losses: list[float] = []
    log_seconds: list[float] = []
    val_rows, val_builder = _validation_builder(validation, pre_cfg, chunk)

    with torch_settings(train_cfg.num_threads):
        model, optimizer = _new_model(demos, sampler, spec, net_cfg, pre_cfg, train_cfg)
        start = time.perf_counter()
        window, paused = 0.0, 0.0  # paused: validation time, kept out of the loop's seconds
        batches = range(1, train_cfg.batches + 1)
        bar = progress_bar(show=progress, iterable=batches, desc="bc", unit="batch")
        for step in bar:
            rows = sampler.sample()
            x, y = builder.inputs(rows), builder.targets(rows)
            loss = ((model(x) - y).square() * weights).sum(dim=1).mean()
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()

            window += loss.item()
            if step % train_cfg.log_every == 0 or step == train_cfg.batches:
                n = step - (log_steps[-1] if log_steps else 0)
                elapsed = time.perf_counter() - start - paused
                sps = step * train_cfg.batch_size / elapsed
                log_steps.append(step)
                log_seconds.append(elapsed)
                losses.append(window / n)
                window = 0.0
                logged = {"loss": losses[-1], "samples_per_s": sps}
                shown = {"loss": f"{losses[-1]:.4f}", "sps": f"{sps:.0f}"}
                if val_builder is not None:
                    t0 = time.perf_counter()
                    val_losses.append(_loss_over(model, val_builder, val_rows, weights))
                    paused += time.perf_counter() - t0
                    logged["val_loss"] = val_losses[-1]
                    shown["val"] = f"{val_losses[-1]:.4f}"
                bar.set_postfix(shown)
                if log_fn is not None:
                    log_fn(step, logged)
        seconds = time.perf_counter() - start - paused
        bar.close()
    model.eval()
    return TrainResult(
        model=model,
        config=BCConfig(pre_cfg, net_cfg, train_cfg),
        log_steps=np.asarray(log_steps, np.int64),
        losses=np.asarray(losses, np.float64),
        seconds=seconds,
        samples_per_s=train_cfg.batches * train_cfg.batch_size / seconds,
        prepare_seconds=prepare_seconds,
        val_losses=None if validation is None else np.asarray(val_losses, np.float64),
        log_seconds=np.asarray(log_seconds, np.float64),
        val_seconds=paused,
    )


def _training_builder(
    demos: Demonstrations, pre_cfg: PreprocessConfig, chunk: int, valid: np.ndarray
) -> tuple[BatchBuilder, float]:
    """The training rows' batch builder, prefilled with the rows the sampler can draw (in
    chunks of one batch's frames when the cache fits), and the seconds it took."""
    cache = BatchBuilder.cache_bytes(demos, pre_cfg) <= CACHE_LIMIT_BYTES
    builder = BatchBuilder(demos, pre_cfg, cache_chunk=chunk if cache else None, reuse_output=True)
    start = time.perf_counter()
    builder.prefill(np.flatnonzero(valid))
    return builder, time.perf_counter() - start


def _check_sampler(sampler: BatchSampler, rows: int, batch_size: int) -> None:
    """The sampler must cover the demonstrations' rows and draw the configured batch size."""
    if len(sampler.mask) != rows:
        raise ValueError(f"sampler covers {len(sampler.mask)} rows, demos have {rows}")
    if sampler.batch_size != batch_size:
        raise ValueError(
            f"sampler.batch_size={sampler.batch_size} != train_cfg.batch_size={batch_size}"
        )


def _validation_builder(
    validation: Demonstrations | None, pre_cfg: PreprocessConfig, chunk: int
) -> tuple[Any, BatchBuilder | None]:
    """The validation set's scored rows and its batch builder (``(None, None)`` without one)."""
    if validation is None:
        return None, None
    rows = np.flatnonzero(validation.scored)
    if not len(rows):
        raise ValueError("the validation set has no scored rows")
    cache = BatchBuilder.cache_bytes(validation, pre_cfg) <= CACHE_LIMIT_BYTES
    return rows, BatchBuilder(validation, pre_cfg, cache_chunk=chunk if cache else None)


def _new_model(
    demos: Demonstrations,
    sampler: BatchSampler,
    spec: ModelSpec,
    net_cfg: NetworkConfig,
    pre_cfg: PreprocessConfig,
    train_cfg: TrainConfig,
) -> tuple[BCNet, torch.optim.Optimizer]:
    """The seeded net (standardized on the sampler's valid rows for vector inputs) in
    training mode and its Adam optimizer; called inside :func:`torch_settings`."""
    torch.manual_seed(train_cfg.seed)
    model = BCNet(spec, pre_cfg, net_cfg)
    if model.vector_input and pre_cfg.standardize:
        mean, std = standardization_stats(demos.observations, sampler.valid)
        k = pre_cfg.frame_stack
        model.set_standardization(np.tile(mean, k), np.tile(std, k))
    optimizer = torch.optim.Adam(
        model.parameters(), lr=train_cfg.lr, weight_decay=train_cfg.weight_decay
    )
    model.train()
    return model, optimizer


def validation_loss(model: BCNet, demos: Demonstrations, train_cfg: TrainConfig) -> float:
    """The loss the curve's ``val_loss`` records, over ``demos``' scored rows: the mean over
    rows of the training loss's weighted squared error (``train_cfg``'s loss weights), in eval
    mode without gradients."""
    chunk = train_cfg.batch_size * model.pre_cfg.frame_stack
    rows, builder = _validation_builder(demos, model.pre_cfg, chunk)
    weights = loss_weights(train_cfg, demos.actions.shape[1])
    return _loss_over(model, builder, rows, weights)


def _loss_over(
    model: BCNet,
    builder: BatchBuilder,
    rows: Any,
    weights: torch.Tensor,
    batch_size: int = 256,
) -> float:
    """The training loss over ``rows`` of ``builder``'s data: the mean over rows of the
    weighted squared error, without gradients, in eval mode (the model's mode restored)."""
    was_training = model.training
    model.eval()
    total = 0.0
    with torch.inference_mode():
        for i in range(0, len(rows), batch_size):
            part = rows[i : i + batch_size]
            err = (model(builder.inputs(part)) - builder.targets(part)).square() * weights
            total += float(err.sum(dim=1).double().sum())
    model.train(was_training)
    return total / len(rows)


def predict(
    model: BCNet,
    demos: Demonstrations,
    rows: np.ndarray | None = None,
    batch_size: int = 256,
) -> np.ndarray:
    """Model actions for ``rows`` (default all) of ``demos``, with training's frame stacking:
    ``(len(rows), A) float32``."""
    builder = BatchBuilder(demos, model.pre_cfg)
    rows = np.arange(len(demos)) if rows is None else np.asarray(rows, np.int64)
    model.eval()
    out = []
    with torch.inference_mode():
        for i in range(0, len(rows), batch_size):
            out.append(model(builder.inputs(rows[i : i + batch_size])).numpy())
    if not out:
        return np.zeros((0, model.spec.action_dim), np.float32)
    return np.concatenate(out).astype(np.float32, copy=False)
