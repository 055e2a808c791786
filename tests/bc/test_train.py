"""train_bc: determinism, learning on a tiny synthetic task, logging, errors, no leaked state."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from safe_bc.bc import PreprocessConfig, TrainConfig, predict, sampler_for, train_bc
from safe_bc.selection import CriticalSubsetWarning, MixedBatchSampler, SelectionConfig, select

from .synth import SMALL_FRAMES, TINY_CNN, TINY_MLP, frame_demos, small_train, vector_demos


def _sampler(demos, cfg: TrainConfig, alpha: float = 0.5):
    sel = select(demos.costs, SelectionConfig(eps=10.0, alpha=alpha), demos.scored)
    return sampler_for(sel, cfg)


def _state(result):
    return {k: v.clone() for k, v in result.model.state_dict().items()}


def test_same_seed_identical_weights_different_seed_differs():
    demos = frame_demos(n=100)
    cfg = small_train(batches=8)
    a = _state(train_bc(demos, _sampler(demos, cfg), TINY_CNN, SMALL_FRAMES, cfg))
    # a used sampler: train_bc restarts its stream from cfg.seed
    sampler = _sampler(demos, cfg)
    sampler.sample()
    b = _state(train_bc(demos, sampler, TINY_CNN, SMALL_FRAMES, cfg))
    assert a.keys() == b.keys()
    assert all(torch.equal(a[k], b[k]) for k in a)
    other = TrainConfig(**{**cfg.__dict__, "seed": 1})
    c = _state(train_bc(demos, _sampler(demos, other), TINY_CNN, SMALL_FRAMES, other))
    assert not all(torch.equal(a[k], c[k]) for k in a)


def test_unset_thread_count_trains_with_one_thread_whatever_the_process_uses():
    """1 and 2 threads give different weights, so ``num_threads=None`` must not mean the
    process's count (the machine's, ``OMP_NUM_THREADS`` or an earlier set_num_threads)."""
    demos = frame_demos(n=60)
    one = small_train(batches=10)
    unset = TrainConfig(**{**one.__dict__, "num_threads": None})
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        result = train_bc(demos, _sampler(demos, unset), TINY_CNN, SMALL_FRAMES, unset)
        assert torch.get_num_threads() == 2  # restored
    finally:
        torch.set_num_threads(threads)
    assert result.config.train.num_threads == 1  # recorded
    a = _state(result)
    b = _state(train_bc(demos, _sampler(demos, one), TINY_CNN, SMALL_FRAMES, one))
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_loss_decreases_on_pixel_task():
    """steer = side of a bright square, gas = its brightness: learnable in a few hundred steps."""
    demos = frame_demos(n=200)
    cfg = TrainConfig(batches=300, batch_size=32, lr=3e-3, log_every=50, num_threads=1)
    result = train_bc(demos, _sampler(demos, cfg, alpha=0.0), TINY_CNN, SMALL_FRAMES, cfg)
    assert result.log_steps.tolist() == [50, 100, 150, 200, 250, 300]
    assert result.losses[-1] < 0.25 * result.losses[0]
    pred = predict(result.model, demos)
    assert np.mean(np.sign(pred[:, 0]) == np.sign(demos.actions[:, 0])) > 0.95  # square's side


def test_vector_mlp_learns_with_standardization():
    demos = vector_demos(n=200)
    cfg = TrainConfig(batches=200, batch_size=32, lr=3e-3, log_every=20, num_threads=1)
    pre = PreprocessConfig(frame_stack=2)
    result = train_bc(demos, _sampler(demos, cfg), TINY_MLP, pre, cfg)
    assert result.model.kind == "mlp" and result.model.input_shape == (10,)
    mean = demos.observations.mean(0)
    np.testing.assert_allclose(result.model.obs_mean.numpy(), np.tile(mean, 2), rtol=1e-5)
    assert result.losses[-1] < 0.2 * result.losses[0]


def test_log_fn_progress_and_summary(monkeypatch):
    import io
    import sys

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    err = Terminal()
    monkeypatch.setattr(sys, "stderr", err)  # the bar is drawn on a terminal only
    demos = frame_demos(n=60)
    cfg = small_train(batches=25)
    calls = []
    result = train_bc(
        demos,
        _sampler(demos, cfg),
        TINY_CNN,
        SMALL_FRAMES,
        cfg,
        progress=True,
        log_fn=lambda step, m: calls.append((step, sorted(m))),
    )
    assert calls == [(s, ["loss", "samples_per_s"]) for s in (10, 20, 25)]
    assert "loss=" in err.getvalue()  # tqdm postfix
    summary = result.summary()
    assert summary["final_loss"] == result.losses[-1] and result.samples_per_s > 0
    assert summary["config"]["train"]["batches"] == 25


def test_global_torch_state_is_restored():
    demos = frame_demos(n=60)
    cfg = small_train(batches=2)
    threads = torch.get_num_threads()
    torch.manual_seed(123)
    expected = torch.rand(3)
    torch.manual_seed(123)
    train_bc(demos, _sampler(demos, cfg), TINY_CNN, SMALL_FRAMES, cfg)
    assert torch.equal(torch.rand(3), expected)
    assert not torch.are_deterministic_algorithms_enabled()
    assert torch.get_num_threads() == threads


def test_warmup_rows_are_never_trained_on():
    demos = frame_demos(n=100, warmup=45)  # 5 scored steps per episode
    cfg = small_train(batches=5)
    sampler = _sampler(demos, cfg)
    rows = np.concatenate([sampler.sample() for _ in range(50)])
    assert not demos.warmup[rows].any()


def test_errors():
    demos = frame_demos(n=60)
    cfg = small_train(batches=2)
    mismatch = MixedBatchSampler(np.ones(60, bool), 1.0, 8, "all", np.random.default_rng(0))
    with pytest.raises(ValueError, match="batch_size"):
        train_bc(demos, mismatch, TINY_CNN, SMALL_FRAMES, cfg)
    short = MixedBatchSampler(np.ones(10, bool), 1.0, 16, "all", np.random.default_rng(0))
    with pytest.raises(ValueError, match="rows"):
        train_bc(demos, short, TINY_CNN, SMALL_FRAMES, cfg)
    weighted = small_train(batches=2, loss_weights=(1.0, 2.0))
    with pytest.raises(ValueError, match="loss_weights"):
        train_bc(demos, _sampler(demos, weighted), TINY_CNN, SMALL_FRAMES, weighted)
    for bad in ({"batches": 0}, {"lr": -1.0}, {"num_threads": 0}, {"loss_weights": (0.0,)}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            TrainConfig(**bad)


def test_loss_weights_change_the_objective():
    demos = frame_demos(n=60)
    plain = small_train(batches=5)
    weighted = small_train(batches=5, loss_weights=(1.0, 0.0, 0.0))
    a = train_bc(demos, _sampler(demos, plain), TINY_CNN, SMALL_FRAMES, plain)
    b = train_bc(demos, _sampler(demos, weighted), TINY_CNN, SMALL_FRAMES, weighted)
    assert a.losses[0] != b.losses[0]


def _cache_cases():
    """(demos, preprocessing, net) triples covering the preprocessing paths."""
    frames = frame_demos(n=90)
    vectors = vector_demos(n=90)
    return [
        (frames, PreprocessConfig(grayscale=True), TINY_CNN),  # (B, 1, H, W): channel stride 1
        (frames, PreprocessConfig(frame_stack=3), TINY_CNN),
        (frames, PreprocessConfig(grayscale=False, resize=24), TINY_CNN),
        (frames, PreprocessConfig(crop_bar=False, frame_stack=2, resize=32), TINY_CNN),
        (vectors, PreprocessConfig(frame_stack=2), TINY_MLP),
        (frames, PreprocessConfig(crop_bar=False, mask_steering=True), TINY_CNN),
    ]


@pytest.mark.parametrize("reuse", [False, True])
@pytest.mark.parametrize("case", range(6))
def test_cached_batches_equal_per_batch_preprocessing(case, reuse):
    """The frame cache hands out the very tensors the per-batch path builds: values and
    strides (the conv kernels, hence the weights' last bits, follow the strides)."""
    from safe_bc.bc.train import BatchBuilder

    demos, pre, _ = _cache_cases()[case]
    rng = np.random.default_rng(case)
    for batch in (1, 5, 16):
        plain = BatchBuilder(demos, pre)
        cached = BatchBuilder(demos, pre, cache_chunk=batch * pre.frame_stack, reuse_output=reuse)
        for _ in range(12):  # repeated rows within and across batches, cache half full
            rows = rng.integers(0, len(demos), batch)
            a, b = plain.inputs(rows), cached.inputs(rows)
            assert a.shape == b.shape and a.dtype == b.dtype
            assert a.stride() == b.stride()
            assert torch.equal(a, b)
            assert torch.equal(plain.targets(rows), cached.targets(rows))
        assert cached._cached.any()


@pytest.mark.parametrize("case", range(6))
def test_frame_cache_leaves_the_weights_unchanged(case, monkeypatch):
    """train_bc with its frame cache gives the weights and losses of the per-batch path (the
    code before the cache), bit for bit."""
    import safe_bc.bc.train as train_mod

    demos, pre, net = _cache_cases()[case]
    cfg = small_train(batches=12)
    cached = train_bc(demos, _sampler(demos, cfg), net, pre, cfg)
    monkeypatch.setattr(train_mod, "CACHE_LIMIT_BYTES", -1)  # every batch preprocessed anew
    plain = train_bc(demos, _sampler(demos, cfg), net, pre, cfg)
    a, b = _state(cached), _state(plain)
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert np.array_equal(cached.losses, plain.losses)


def test_training_warns_when_every_scored_row_is_critical():
    """The run still trains (alpha has no effect then), but says so once, with eps."""
    from safe_bc.bc import BCConfig
    from safe_bc.methods.experiment import RunConfig, train_run

    demos = vector_demos(n=60)  # costs in [0, 40)
    bc = BCConfig(PreprocessConfig(), TINY_MLP, small_train(batches=2))
    run = RunConfig(SelectionConfig(eps=50.0, alpha=0.5), bc)
    with pytest.warns(CriticalSubsetWarning, match=r"critical fraction 1\) at eps=50 "):
        result, selection = train_run(demos, run)
    assert selection.n_critical == selection.n_valid and len(result.losses) == 1


def test_validation_loss_is_recorded_and_changes_no_weight():
    """The validation pass reads no random number and touches no weight: the same weights and
    training losses with and without it; its loss is finite at every log point."""
    from safe_bc.data.demos import hold_out_episodes

    train, held = hold_out_episodes(frame_demos(n=150), 1)  # episodes of 50 steps
    assert len(train) == 100 and set(held.episode_ids.tolist()) == {2}
    cfg = small_train(batches=25)
    plain = train_bc(train, _sampler(train, cfg), TINY_CNN, SMALL_FRAMES, cfg)
    calls = []
    checked = train_bc(
        train,
        _sampler(train, cfg),
        TINY_CNN,
        SMALL_FRAMES,
        cfg,
        log_fn=lambda step, m: calls.append(sorted(m)),
        validation=held,
    )
    a, b = _state(plain), _state(checked)
    assert all(torch.equal(a[k], b[k]) for k in a)
    np.testing.assert_array_equal(plain.losses, checked.losses)
    assert plain.val_losses is None and "val_losses" not in plain.summary()
    assert checked.val_losses.shape == checked.log_steps.shape
    assert np.isfinite(checked.val_losses).all() and (checked.val_losses > 0).all()
    assert calls[-1] == ["loss", "samples_per_s", "val_loss"]
    # the loss over the held-out rows, recomputed outside the loop
    pred = predict(checked.model, held)
    mse = ((pred - held.actions) ** 2).mean(axis=1).mean()
    assert checked.val_losses[-1] == pytest.approx(mse, rel=1e-5)


def test_curve_table_has_one_row_per_log_point():
    demos = frame_demos(n=60)
    cfg = small_train(batches=25)
    curve = train_bc(demos, _sampler(demos, cfg), TINY_CNN, SMALL_FRAMES, cfg).curve()
    assert list(curve.columns) == ["batch", "train_loss", "val_loss", "samples", "seconds"]
    assert curve["batch"].tolist() == [10, 20, 25]
    assert curve["samples"].tolist() == [160, 320, 400]
    assert curve["val_loss"].isna().all() and curve["seconds"].is_monotonic_increasing


def test_hold_out_needs_an_episode_left_for_training():
    from safe_bc.data.demos import hold_out_episodes

    demos = frame_demos(n=100)  # two episodes
    with pytest.raises(ValueError, match="at least one must stay for training"):
        hold_out_episodes(demos, 2)
    with pytest.raises(ValueError, match="integer >= 1"):
        hold_out_episodes(demos, 0)
