"""Frames and vectors -> network inputs; frame stacking at episode boundaries."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from safe_bc.bc import PreprocessConfig, frame_stack_index, gather_inputs, input_shape
from safe_bc.bc.preprocess import preprocess, preprocess_frames, stack, standardization_stats

from .synth import frame_demos


def test_frame_shapes_and_range():
    frames = np.random.default_rng(0).integers(0, 256, (5, 96, 96, 3), dtype=np.uint8)
    frames[0] = 255
    grey_cropped = PreprocessConfig(grayscale=True, crop_bar=True)
    for cfg, shape in [
        (grey_cropped, (1, 84, 96)),
        (PreprocessConfig(grayscale=False, crop_bar=True), (3, 84, 96)),
        (PreprocessConfig(grayscale=True, crop_bar=False), (1, 96, 96)),
        (PreprocessConfig(grayscale=True, resize=32), (1, 32, 32)),
        (PreprocessConfig(grayscale=False, crop_bar=False, resize=48), (3, 48, 48)),
    ]:
        x = preprocess_frames(frames, cfg)
        assert x.shape == (5, *shape) == (5, *input_shape((96, 96, 3), cfg))
        assert x.dtype == torch.float32
        assert x.min() >= 0.0 and x.max() <= 1.0
    assert torch.allclose(preprocess_frames(frames[:1], grey_cropped), torch.tensor(1.0))


def test_grayscale_weights_and_rgb_channel_order():
    frames = np.zeros((3, 96, 96, 3), np.uint8)
    for c in range(3):
        frames[c, ..., c] = 255
    gray = preprocess_frames(frames, PreprocessConfig(grayscale=True))[:, 0, 0, 0]
    assert np.allclose(gray.numpy(), [0.299, 0.587, 0.114], atol=1e-6)
    rgb = preprocess_frames(frames, PreprocessConfig(grayscale=False, mask_steering=False))
    assert rgb[1, 1].min() == 1.0 and rgb[1, 0].max() == 0.0 and rgb[1, 2].max() == 0.0


def test_crop_drops_the_indicator_bar():
    frames = np.zeros((2, 96, 96, 3), np.uint8)
    frames[:, 84:] = 255  # the bar
    assert preprocess_frames(frames, PreprocessConfig(crop_bar=True)).max() == 0.0
    assert preprocess_frames(frames, PreprocessConfig(crop_bar=False)).max() == 1.0


def _preprocess_reference(frames: np.ndarray, cfg: PreprocessConfig) -> torch.Tensor:
    """The straightforward order (mask a copy of the input, crop, convert, resize): what
    ``preprocess_frames`` computed before it stopped copying the input."""
    import torch.nn.functional as F

    from safe_bc.bc.preprocess import _LUMA_ROW, BAR_ROWS, STEERING_INDICATOR

    x = torch.as_tensor(frames).clone()
    if cfg.mask_steering:
        x[:, STEERING_INDICATOR[0], STEERING_INDICATOR[1]] = 0
    if cfg.crop_bar:
        x = x[:, : x.shape[1] - BAR_ROWS]
    if cfg.grayscale:
        x = F.linear(x.float(), _LUMA_ROW).clamp_(0.0, 1.0).permute(0, 3, 1, 2)
    else:
        x = x.permute(0, 3, 1, 2).float() / 255.0
    if cfg.resize is not None:
        x = F.interpolate(x, size=(cfg.resize, cfg.resize), mode="area")
    return x.contiguous()


@pytest.mark.parametrize("grayscale", [False, True])
@pytest.mark.parametrize("crop_bar", [False, True])
@pytest.mark.parametrize("mask_steering", [False, True])
@pytest.mark.parametrize("resize", [None, 48])
def test_frames_are_the_reference_order_bit_for_bit(grayscale, crop_bar, mask_steering, resize):
    """Masking the converted frame (no copy of the input) gives the same bits as masking the
    input; the input is left as it was."""
    cfg = PreprocessConfig(grayscale=grayscale, crop_bar=crop_bar,
                           mask_steering=mask_steering, resize=resize)  # fmt: skip
    frames = np.random.default_rng(1).integers(0, 256, (3, 96, 96, 3), dtype=np.uint8)
    kept = frames.copy()
    for batch in (frames, frames[1:2]):
        got, want = preprocess_frames(batch, cfg), _preprocess_reference(batch, cfg)
        assert got.is_contiguous() and got.dtype == want.dtype
        assert torch.equal(got.view(torch.int32), want.view(torch.int32))  # bits, signs of 0
    np.testing.assert_array_equal(frames, kept)


def test_vectors_pass_through():
    obs = np.arange(12, dtype=np.float32).reshape(3, 4)
    x = preprocess(obs, PreprocessConfig())
    assert x.dtype == torch.float32 and torch.equal(x, torch.from_numpy(obs))
    assert input_shape((4,), PreprocessConfig(frame_stack=3)) == (12,)


def test_bad_inputs():
    with pytest.raises(ValueError, match="uint8"):
        preprocess_frames(np.zeros((2, 96, 96, 3), np.float32), PreprocessConfig())
    with pytest.raises(ValueError, match="frames"):
        input_shape((96, 96), PreprocessConfig())
    with pytest.raises(ValueError, match="frame_stack"):
        PreprocessConfig(frame_stack=0)
    with pytest.raises(ValueError, match="resize"):
        PreprocessConfig(resize=2)


def test_stack_index_at_episode_boundaries():
    ep = np.array([0, 0, 0, 0, 1, 1, 2])
    st = np.array([0, 1, 2, 3, 0, 1, 0])
    idx = frame_stack_index(ep, st, 3)
    assert idx.tolist() == [
        [0, 0, 0],
        [0, 0, 1],
        [0, 1, 2],
        [1, 2, 3],
        [4, 4, 4],
        [4, 4, 5],
        [6, 6, 6],
    ]
    assert frame_stack_index(ep, st, 1).tolist() == [[i] for i in range(7)]


def test_stack_index_unsorted_rows_and_gaps():
    rng = np.random.default_rng(0)
    ep = np.array([0, 0, 0, 1, 1, 1])
    st = np.array([0, 1, 2, 0, 1, 2])
    perm = rng.permutation(6)
    idx = frame_stack_index(ep[perm], st[perm], 2)
    inv = np.argsort(perm)
    # row inv[j] holds original row j; its predecessor is original row j-1 in the episode
    for j in range(6):
        want_prev = j - 1 if st[j] > 0 else j
        assert idx[inv[j]].tolist() == [inv[want_prev], inv[j]]
    # a missing step restarts the stack (no frame from before the gap)
    gap = frame_stack_index(np.zeros(3, int), np.array([0, 1, 5]), 2)
    assert gap.tolist() == [[0, 0], [0, 1], [2, 2]]
    with pytest.raises(ValueError, match="duplicate"):
        frame_stack_index(np.zeros(2, int), np.zeros(2, int), 2)


def test_gather_stacks_consecutive_frames_oldest_first():
    demos = frame_demos(n=100)  # two episodes of 50
    cfg = PreprocessConfig(frame_stack=3, resize=24, grayscale=True)
    sidx = frame_stack_index(demos.episode_ids, demos.steps, 3)
    rows = np.array([0, 1, 2, 49, 50, 51, 99])
    x = gather_inputs(demos.observations, rows, cfg, sidx)
    assert x.shape == (7, 3, 24, 24)
    single = preprocess_frames(demos.observations, PreprocessConfig(resize=24, grayscale=True))
    single = single[:, 0]
    expect = {0: [0, 0, 0], 1: [0, 0, 1], 2: [0, 1, 2], 49: [47, 48, 49], 50: [50, 50, 50]}
    expect |= {51: [50, 50, 51], 99: [97, 98, 99]}
    for b, r in enumerate(rows):
        for c, src in enumerate(expect[int(r)]):
            assert torch.equal(x[b, c], single[src])
    with pytest.raises(ValueError, match="stack_index"):
        gather_inputs(demos.observations, rows, cfg)


def test_stack_vectors_and_rgb_channel_grouping():
    v = torch.arange(12.0).reshape(6, 2)
    assert stack(v, 3).tolist() == [[0, 1, 2, 3, 4, 5], [6, 7, 8, 9, 10, 11]]
    img = torch.arange(4.0).reshape(4, 1, 1, 1).expand(4, 3, 2, 2)
    s = stack(img, 2)
    assert s.shape == (2, 6, 2, 2)
    assert s[0, :3].eq(0).all() and s[0, 3:].eq(1).all() and s[1, 3:].eq(3).all()


def test_standardization_stats():
    obs = np.array([[1.0, 5.0], [3.0, 5.0], [100.0, 0.0]], np.float32)
    mean, std = standardization_stats(obs, np.array([True, True, False]))
    assert mean.tolist() == [2.0, 5.0] and std.tolist() == [1.0, 1.0]  # constant -> 1
    assert mean.dtype == np.float32
