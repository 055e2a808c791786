"""Training on streamed frames (a ``FrameFile``) is training on the in-memory frames: the
same batches, inputs, losses and weights for a seed, with and without the frame cache."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from safe_bc.bc import PreprocessConfig, sampler_for, train_bc
from safe_bc.data.frames import FrameFile, write_frame_file
from safe_bc.selection import SelectionConfig, select

from .synth import TINY_CNN, frame_demos, small_train


def _record(monkeypatch) -> list[tuple[np.ndarray, torch.Tensor]]:
    """Every ``BatchBuilder.inputs`` call of the next trainings: ``(rows, inputs)``."""
    from safe_bc.bc.train import BatchBuilder

    calls: list[tuple[np.ndarray, torch.Tensor]] = []
    inputs = BatchBuilder.inputs

    def recorded(self, rows):
        x = inputs(self, rows)
        calls.append((np.array(rows), x.clone()))
        return x

    monkeypatch.setattr(BatchBuilder, "inputs", recorded)
    return calls


@pytest.mark.parametrize("cache", [True, False])
@pytest.mark.parametrize(
    "pre", [PreprocessConfig(), PreprocessConfig(grayscale=True, frame_stack=3, resize=32)]
)
def test_streamed_frames_train_the_same_weights(tmp_path, monkeypatch, pre, cache):
    import safe_bc.bc.train as train_mod

    if not cache:
        monkeypatch.setattr(train_mod, "CACHE_LIMIT_BYTES", -1)  # every batch preprocessed
    demos = frame_demos(n=90)
    path = write_frame_file(tmp_path / "frames.npy", demos.observations.shape, [demos.observations])
    streamed = replace(demos, observations=FrameFile(path, demos.observations.shape))
    cfg = small_train(batches=6)
    calls = _record(monkeypatch)
    results = []
    for d in (demos, streamed):
        sel = select(d.costs, SelectionConfig(eps=10.0, alpha=0.5), d.scored)
        sampler = sampler_for(sel, cfg)
        results.append(train_bc(d, sampler, TINY_CNN, pre, cfg))
    mem, stream = calls[: len(calls) // 2], calls[len(calls) // 2 :]
    assert len(mem) == len(stream) == cfg.batches
    for (rows_a, x_a), (rows_b, x_b) in zip(mem, stream, strict=True):
        assert np.array_equal(rows_a, rows_b)
        assert torch.equal(x_a, x_b) and x_a.stride() == x_b.stride()
    a, b = (r.model.state_dict() for r in results)
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert np.array_equal(results[0].losses, results[1].losses)
