"""Checkpoint round trip and clear errors for missing / corrupt checkpoints."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest
import torch

from safe_bc.bc import (
    BCConfig,
    BCNet,
    BCPolicy,
    CheckpointError,
    CheckpointNotFoundError,
    ModelSpec,
    PreprocessConfig,
    load_checkpoint,
    read_checkpoint_meta,
    save_checkpoint,
    train_bc,
)
from safe_bc.bc.checkpoint import with_meta_sha256
from safe_bc.selection import MixedBatchSampler

from .synth import SMALL_FRAMES, TINY_CNN, TINY_MLP, frame_demos, small_train, vector_demos


def _train(demos, pre, net):
    cfg = small_train(batches=3)
    sampler = MixedBatchSampler(
        np.ones(len(demos), bool), 0.5, cfg.batch_size, "all", np.random.default_rng(0)
    )
    return train_bc(demos, sampler, net, pre, cfg)


@pytest.fixture(scope="module")
def frame_ckpt(tmp_path_factory):
    demos = frame_demos(n=60)
    pre = PreprocessConfig(frame_stack=2, resize=24)
    result = _train(demos, pre, TINY_CNN)
    directory = tmp_path_factory.mktemp("ckpt") / "run"
    result.save(directory, extra={"alpha": 0.5, "selection": {"n_critical": 3}})
    return demos, result, directory


def test_roundtrip_identical_outputs(frame_ckpt):
    demos, result, directory = frame_ckpt
    model, configs = load_checkpoint(directory)
    assert configs == result.config
    assert model.spec == result.model.spec and not model.training
    x = torch.rand(5, *model.input_shape)
    with torch.no_grad():
        assert torch.equal(model(x), result.model(x))
    a, b = BCPolicy.from_checkpoint(directory), result.policy()
    for obs in demos.observations[:4]:
        np.testing.assert_array_equal(a.act(obs, None), b.act(obs, None))


def test_meta_and_no_temp_files(frame_ckpt):
    _, _, directory = frame_ckpt
    meta = read_checkpoint_meta(directory)
    assert meta["extra"] == {"alpha": 0.5, "selection": {"n_critical": 3}}
    assert meta["config"]["preprocess"]["frame_stack"] == 2
    assert sorted(p.name for p in directory.iterdir()) == ["config.json", "weights.pt"]


def test_vector_roundtrip_keeps_standardization_and_unbounded_actions(tmp_path):
    demos = vector_demos(n=60)
    result = _train(demos, PreprocessConfig(), TINY_MLP)
    assert result.model.spec.action_low == (-np.inf, -np.inf)
    save_checkpoint(tmp_path, result.model, result.config)
    assert json.loads((tmp_path / "config.json").read_text())["spec"]["action_low"] == [None] * 2
    model, _ = load_checkpoint(tmp_path)
    assert torch.equal(model.obs_mean, result.model.obs_mean)
    np.testing.assert_array_equal(
        BCPolicy(model).act_batch(demos.observations), result.policy().act_batch(demos.observations)
    )


def test_overwrite_replaces_checkpoint(tmp_path):
    spec = ModelSpec.for_data((96, 96, 3), 3)
    cfg = BCConfig(SMALL_FRAMES, TINY_CNN)
    torch.manual_seed(0)
    save_checkpoint(tmp_path, BCNet(spec, SMALL_FRAMES, TINY_CNN), cfg)
    torch.manual_seed(1)
    second = BCNet(spec, SMALL_FRAMES, TINY_CNN)
    save_checkpoint(tmp_path, second, cfg)
    loaded, _ = load_checkpoint(tmp_path)
    want = second.state_dict()
    assert all(torch.equal(v, want[k]) for k, v in loaded.state_dict().items())


def test_missing(tmp_path):
    with pytest.raises(CheckpointNotFoundError, match="no checkpoint directory"):
        load_checkpoint(tmp_path / "nope")
    with pytest.raises(CheckpointNotFoundError, match=r"missing config\.json"):
        load_checkpoint(tmp_path)
    assert issubclass(CheckpointNotFoundError, FileNotFoundError)


def _copy(src, dst):
    dst.mkdir()
    for name in ("weights.pt", "config.json"):
        (dst / name).write_bytes((src / name).read_bytes())
    return dst


def test_corrupt(frame_ckpt, tmp_path):
    _, _, src = frame_ckpt

    d = _copy(src, tmp_path / "noweights")
    (d / "weights.pt").unlink()
    with pytest.raises(CheckpointNotFoundError, match=r"missing weights\.pt"):
        load_checkpoint(d)

    d = _copy(src, tmp_path / "badjson")
    (d / "config.json").write_text("{not json")
    with pytest.raises(CheckpointError, match="malformed"):
        load_checkpoint(d)

    d = _copy(src, tmp_path / "otherformat")
    (d / "config.json").write_text(json.dumps({"format": "x"}))
    with pytest.raises(CheckpointError, match="format"):
        load_checkpoint(d)

    d = _copy(src, tmp_path / "truncated")
    (d / "weights.pt").write_bytes((d / "weights.pt").read_bytes()[:100])
    with pytest.raises(CheckpointError, match="sha256"):
        load_checkpoint(d)

    d = _copy(src, tmp_path / "badconfig")
    meta = json.loads((d / "config.json").read_text())
    meta["config"]["network"]["hidden"] = -3
    (d / "config.json").write_text(json.dumps(with_meta_sha256(meta)))
    with pytest.raises(CheckpointError, match="hidden"):
        load_checkpoint(d)

    d = _copy(src, tmp_path / "garbage")
    (d / "weights.pt").write_bytes(b"garbage")
    meta = json.loads((d / "config.json").read_text())
    meta["weights_sha256"] = hashlib.sha256(b"garbage").hexdigest()
    (d / "config.json").write_text(json.dumps(with_meta_sha256(meta)))
    with pytest.raises(CheckpointError, match="cannot load weights"):
        load_checkpoint(d)


def test_unserialisable_extra_writes_nothing(tmp_path):
    demos = vector_demos(n=30)
    result = _train(demos, PreprocessConfig(), TINY_MLP)
    with pytest.raises(ValueError, match="JSON"):
        result.save(tmp_path / "x", extra={"arr": np.zeros(2)})
    with pytest.raises(ValueError, match="JSON"):
        result.save(tmp_path / "y", extra={"loss": float("nan")})
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()
