"""Errors a person can act on: unsafe checkpoints and stray files in a dataset."""

from __future__ import annotations

import hashlib
import json
import pathlib
from pathlib import Path

import pandas as pd
import pytest
import torch

from safe_bc.bc import BCConfig, BCNet, CheckpointError, ModelSpec, load_checkpoint, save_checkpoint
from safe_bc.bc.checkpoint import UnsafeCheckpointError
from safe_bc.cli import main
from safe_bc.data.store import (
    DatasetError,
    completed_episodes,
    init_dataset,
    load_demonstrations,
    read_episodes,
    write_episode,
)

from .bc.synth import TINY_MLP
from .data.test_store import make_episode, make_meta


def _unsafe_checkpoint(directory: Path) -> Path:
    """A real checkpoint whose weights.pt also pickles a non-tensor object (sha256 updated,
    so only safe loading stands in the way)."""
    spec = ModelSpec.for_data((5,), 2)
    cfg = BCConfig(network=TINY_MLP)
    model = BCNet(spec, cfg.preprocess, cfg.network)
    save_checkpoint(directory, model, cfg)
    weights = directory / "weights.pt"
    state = dict(model.state_dict())
    state["note"] = pathlib.PurePosixPath("not/a/tensor")
    torch.save(state, weights)
    meta = json.loads((directory / "config.json").read_text())
    meta["weights_sha256"] = hashlib.sha256(weights.read_bytes()).hexdigest()
    (directory / "config.json").write_text(json.dumps(meta))
    return weights


def test_unsafe_checkpoint_is_one_typed_line_naming_the_file(tmp_path: Path) -> None:
    weights = _unsafe_checkpoint(tmp_path / "ckpt")
    with pytest.raises(UnsafeCheckpointError) as info:
        load_checkpoint(tmp_path / "ckpt")
    message = str(info.value)
    assert isinstance(info.value, CheckpointError)
    assert str(weights) in message and "pathlib.PurePosixPath" in message
    assert "\n" not in message
    assert "weights_only=False" not in message and "weights_only` set to `False" not in message
    assert info.value.__cause__ is None and info.value.__suppress_context__


def test_cli_unsafe_checkpoint_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    weights = _unsafe_checkpoint(tmp_path / "ckpt")
    code = main(["evaluate", "--checkpoint", str(tmp_path / "ckpt"), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and str(weights) in err
    assert err.startswith("safe-bc evaluate: error: ")
    assert "False" not in err


def test_corrupt_weights_are_one_line(tmp_path: Path) -> None:
    spec = ModelSpec.for_data((5,), 2)
    cfg = BCConfig(network=TINY_MLP)
    save_checkpoint(tmp_path, BCNet(spec, cfg.preprocess, cfg.network), cfg)
    weights = tmp_path / "weights.pt"
    torch.save({"other": torch.zeros(3)}, weights)  # loads safely, fits no net
    meta = json.loads((tmp_path / "config.json").read_text())
    meta["weights_sha256"] = hashlib.sha256(weights.read_bytes()).hexdigest()
    (tmp_path / "config.json").write_text(json.dumps(meta))
    with pytest.raises(CheckpointError, match="do not fit the net") as info:
        load_checkpoint(tmp_path)
    assert "\n" not in str(info.value) and str(weights) in str(info.value)


@pytest.mark.parametrize("name", ["notes.parquet", "episode-1.parquet", "episode-x.parquet"])
def test_stray_parquet_in_episodes_is_named(tmp_path: Path, name: str) -> None:
    meta = init_dataset(tmp_path, make_meta("raw"))
    write_episode(tmp_path, make_episode(0, n=4), meta)
    stray = tmp_path / "episodes" / name
    pd.DataFrame({"x": [1, 2]}).to_parquet(stray)
    for call in (
        lambda: completed_episodes(tmp_path, meta),
        lambda: read_episodes(tmp_path),
        lambda: load_demonstrations(tmp_path),
    ):
        with pytest.raises(DatasetError, match="not an episode file") as info:
            call()
        assert str(stray) in str(info.value) and "\n" not in str(info.value)
    stray.unlink()
    (tmp_path / "episodes" / ".episode-00001.parquet.abc.tmp").write_bytes(b"partial")
    (tmp_path / "episodes" / "README.txt").write_text("not parquet: left alone")
    assert completed_episodes(tmp_path, meta) == [0]


def test_cli_stray_parquet_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    meta = init_dataset(tmp_path / "demos", make_meta("raw"))
    write_episode(tmp_path / "demos", make_episode(0, n=4), meta)
    pd.DataFrame({"x": [1]}).to_parquet(tmp_path / "demos" / "episodes" / "extra.parquet")
    code = main(["describe", "--demos", str(tmp_path / "demos"), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and "extra.parquet" in err and "not an episode file" in err
