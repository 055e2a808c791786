"""BCNet output bounds, BCPolicy frame buffer, and agreement between training and acting."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from safe_bc.bc import (
    CAR_RACING_BOUNDS,
    BCNet,
    BCPolicy,
    ModelSpec,
    NetworkConfig,
    PreprocessConfig,
    predict,
)
from safe_bc.policy import Policy

from .synth import SMALL_FRAMES, TINY_CNN, TINY_MLP, frame_demos, vector_demos


def _net(spec, pre=SMALL_FRAMES, net=TINY_CNN, seed=0) -> BCNet:
    torch.manual_seed(seed)
    return BCNet(spec, pre, net).eval()


def _blow_up(model: BCNet, scale: float = 1e3) -> None:
    """Make the pre-activations huge so that the squashing saturates."""
    with torch.no_grad():
        model.head[-1].weight.mul_(scale)
        model.head[-1].bias.zero_()


def _set_output(model: BCNet, z: float) -> None:
    """Make the last layer output the constant pre-activation ``z``."""
    with torch.no_grad():
        model.head[-1].weight.zero_()
        model.head[-1].bias.fill_(z)


def test_cnn_output_shape_and_carracing_ranges():
    spec = ModelSpec.for_data((96, 96, 3), 3)
    assert (spec.action_low, spec.action_high) == CAR_RACING_BOUNDS
    model = _net(spec)
    _blow_up(model)
    out = model(torch.rand(64, 1, 24, 24))
    assert out.shape == (64, 3) and out.dtype == torch.float32
    steer, pedals = out[:, 0], out[:, 1:]
    assert steer.min() >= -1 and steer.max() <= 1 and pedals.min() >= 0 and pedals.max() <= 1
    x = torch.rand(2, 1, 24, 24)
    _set_output(model, 50.0)
    assert torch.allclose(model(x), torch.tensor([[1.0, 1.0, 1.0]] * 2))
    _set_output(model, -50.0)
    assert torch.allclose(model(x), torch.tensor([[-1.0, 0.0, 0.0]] * 2))
    _set_output(model, 0.0)
    assert model(x).tolist() == [[0.0, 0.5, 0.5]] * 2  # tanh(0), sigmoid(0)


def test_mlp_bounds_general_and_unbounded():
    spec = ModelSpec.for_data((4,), 3, ((-2.0, 1.0, -math.inf), (2.0, 3.0, math.inf)))
    model = _net(spec, PreprocessConfig(), TINY_MLP)
    assert model.kind == "mlp"
    _blow_up(model)
    out = model(torch.randn(512, 4) * 10)
    assert out[:, 0].abs().max() <= 2 and out[:, 0].abs().max() > 1.5
    assert out[:, 1].min() >= 1 and out[:, 1].max() <= 3
    assert out[:, 2].abs().max() > 3  # identity: not squashed
    default = ModelSpec.for_data((4,), 2)
    assert default.action_low == (-math.inf, -math.inf)


def test_spec_roundtrip_and_validation():
    spec = ModelSpec.for_data((4,), 2, ((-1.0, -math.inf), (1.0, math.inf)))
    d = spec.to_dict()
    assert d["action_low"] == [-1.0, None]
    assert ModelSpec.from_dict(d) == spec
    with pytest.raises(ValueError, match="low < high"):
        ModelSpec((4,), (1.0,), (0.0,))
    with pytest.raises(ValueError, match="CNN"):
        BCNet(spec, PreprocessConfig(), NetworkConfig(kind="cnn"))
    with pytest.raises(ValueError, match="too small"):
        BCNet(ModelSpec.for_data((96, 96, 3), 3), PreprocessConfig(resize=8), NetworkConfig())


def test_policy_protocol_and_act():
    demos = frame_demos(n=60)
    policy = BCPolicy(_net(ModelSpec.for_data((96, 96, 3), 3)))
    assert isinstance(policy, Policy)
    policy.reset(None, np.random.default_rng(0))
    a = policy.act(demos.observations[0], None)
    assert a.shape == (3,) and a.dtype == np.float32
    assert -1 <= a[0] <= 1 and (a[1:] >= 0).all() and (a[1:] <= 1).all()
    with pytest.raises(ValueError, match="shape"):
        policy.act(np.zeros((96, 96), np.uint8), None)


@pytest.mark.parametrize("k", [1, 3])
def test_acting_through_an_episode_matches_training_inputs(k):
    """The policy's frame buffer builds the same stacks as training does from episode/step."""
    demos = frame_demos(n=100)  # two episodes of 50 steps
    pre = PreprocessConfig(frame_stack=k, resize=24)
    model = _net(ModelSpec.for_data((96, 96, 3), 3), pre)
    offline = predict(model, demos)
    policy = BCPolicy(model)
    online = []
    for ep in (0, 1):
        policy.reset(None, np.random.default_rng(0))
        online += [policy.act(o, None) for o in demos.observations[demos.episode_ids == ep]]
    np.testing.assert_allclose(np.stack(online), offline, rtol=0, atol=1e-6)


def test_reset_clears_the_frame_buffer():
    demos = frame_demos(n=10)
    pre = PreprocessConfig(frame_stack=2, resize=24)
    policy = BCPolicy(_net(ModelSpec.for_data((96, 96, 3), 3), pre))
    first = policy.act(demos.observations[5], None)
    policy.act(demos.observations[6], None)
    policy.reset(None, np.random.default_rng(0))
    np.testing.assert_array_equal(policy.act(demos.observations[5], None), first)


def test_act_batch_forms():
    demos = frame_demos(n=8)
    pre = PreprocessConfig(frame_stack=2, resize=24)
    policy = BCPolicy(_net(ModelSpec.for_data((96, 96, 3), 3), pre))
    obs = demos.observations
    single = policy.act_batch(obs[:4])
    assert single.shape == (4, 3) and single.dtype == np.float32
    stacked = policy.act_batch(np.stack([obs[:4], obs[:4]], axis=1))
    np.testing.assert_array_equal(single, stacked)  # repeated frame == start of an episode
    policy.reset(None, None)
    np.testing.assert_allclose(policy.act(obs[2], None), single[2], atol=1e-6)
    with pytest.raises(ValueError, match="obs_batch"):
        policy.act_batch(np.stack([obs[:4]] * 3, axis=1))


def test_vector_policy_standardizes_inside_the_model():
    demos = vector_demos(n=20, d=3)
    model = _net(ModelSpec.for_data((3,), 2), PreprocessConfig(), TINY_MLP)
    before = model(torch.from_numpy(demos.observations))
    model.set_standardization(np.full(3, 50.0), np.full(3, 10.0))
    after = BCPolicy(model).act_batch(demos.observations)
    z = torch.from_numpy((demos.observations - 50) / 10)
    model.set_standardization(np.zeros(3), np.ones(3))
    np.testing.assert_allclose(after, model(z).detach().numpy(), atol=1e-5)
    assert not np.allclose(after, before.detach().numpy())
    with pytest.raises(ValueError, match="std"):
        model.set_standardization(np.zeros(3), np.zeros(3))


def test_network_config_layers():
    cfg = NetworkConfig(channels=(8, 8, 8, 8), kernel_sizes=(3,), strides=(2,))
    assert cfg.kernel_sizes == (3, 3, 3, 3) and cfg.strides == (2, 2, 2, 2)
    flat = NetworkConfig(channels=())
    assert flat.kernel_sizes == () and flat.strides == ()
    model = BCNet(ModelSpec.for_data((96, 96, 3), 3), SMALL_FRAMES, flat)
    assert model(torch.rand(2, 1, 24, 24)).shape == (2, 3)
    with pytest.raises(ValueError, match="equal lengths"):
        NetworkConfig(channels=(4, 8))  # two layers, three default kernels
    for bad in ({"hidden": 0}, {"kind": "rnn"}, {"channels": (4, -1, 2)}, {"mlp_layers": -1}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            NetworkConfig(**bad)


@pytest.mark.parametrize("batch", [2, 3, 5])
def test_forward_rows_is_one_row_at_a_time_bit_for_bit(batch):
    """The default CarRacing net: forward_rows is one-row passes, whatever the batch."""
    torch.set_num_threads(1)
    spec = ModelSpec.for_data((96, 96, 3), 3, CAR_RACING_BOUNDS)
    model = _net(spec, pre=PreprocessConfig(), net=NetworkConfig())
    x = torch.rand((batch, *model.input_shape), generator=torch.Generator().manual_seed(batch))
    with torch.inference_mode():
        rows = torch.cat([model(x[i : i + 1]) for i in range(batch)])
        assert torch.equal(model.forward_rows(x), rows)


@pytest.mark.parametrize("forward", ["rows", "batched"])
def test_act_slots_is_act_in_each_episode(forward):
    """Two interleaved episodes (stacked frames, one slot idle for a step) get the actions a
    fresh policy gives each episode on its own: bit for bit one row at a time, up to the
    rounding of a batched forward pass with ``forward="batched"``."""
    spec = ModelSpec.for_data((96, 96, 3), 3, CAR_RACING_BOUNDS)
    pre = replace(SMALL_FRAMES, frame_stack=2, mask_steering=False)
    model = _net(spec, pre=pre)
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 256, (2, 4, 96, 96, 3), dtype=np.uint8)
    batched = BCPolicy(model)
    batched.reset_slots(2)
    got: list[list[np.ndarray]] = [[], []]
    for t in range(4):
        slots = np.array([0, 1]) if t != 2 else np.array([1])
        acts = batched.act_slots(frames[slots, t], slots, forward)
        for slot, a in zip(slots, acts, strict=True):
            got[slot].append(a)
    a0 = BCPolicy(model)
    expected0 = [a0.act(frames[0, t]) for t in (0, 1, 3)]
    a1 = BCPolicy(model)
    expected1 = [a1.act(frames[1, t]) for t in range(4)]
    for slot, expected in ((0, expected0), (1, expected1)):
        if forward == "rows":
            np.testing.assert_array_equal(np.stack(got[slot]), np.stack(expected))
        else:
            # the episodes' actions differ by ~1e-5 (random frames), rounding by ~1e-7
            np.testing.assert_allclose(np.stack(got[slot]), np.stack(expected), rtol=0, atol=1e-6)
    assert not np.array_equal(expected0[0], expected1[0])  # the slots hold different episodes


def test_forward_rows_of_a_vector_net_is_one_row_at_a_time():
    """The MLP path (standardisation, a flatten body) gives the same bits as well."""
    model = _net(ModelSpec.for_data((3,), 2), PreprocessConfig(), TINY_MLP)
    model.set_standardization(np.full(3, 50.0), np.full(3, 10.0))
    x = torch.from_numpy(vector_demos(n=5, d=3).observations)
    with torch.inference_mode():
        rows = torch.cat([model(x[i : i + 1]) for i in range(len(x))])
        assert torch.equal(model.forward_rows(x), rows)
