"""The improvement scripts reuse a stored start only when it was trained as asked."""

import json
from dataclasses import asdict, replace
from pathlib import Path

import pytest

from safe_bc.bc import PreprocessConfig
from scripts.improve_rehab import ensure_start


def _start(tmp_path: Path, alpha: float, preprocess: dict, obs_shape: list[int]) -> Path:
    out = tmp_path / "start"
    out.mkdir()
    run = {"selection": {"alpha": alpha}, "bc": {"preprocess": preprocess}}
    stored = {"spec": {"obs_shape": obs_shape}, "extra": {"run": run}}
    (out / "config.json").write_text(json.dumps(stored))
    return out


def test_matching_start_is_reused(tmp_path):
    out = _start(tmp_path, 0.1, asdict(PreprocessConfig()), [96, 96, 3])
    assert ensure_start(tmp_path / "no_demos", out, 0, 0.1) == out


def test_start_with_other_alpha_is_refused(tmp_path):
    out = _start(tmp_path, 0.5, asdict(PreprocessConfig()), [96, 96, 3])
    with pytest.raises(SystemExit, match=r"alpha 0\.5"):
        ensure_start(tmp_path / "no_demos", out, 0, 0.1)


def test_pixel_start_with_other_preprocessing_is_refused(tmp_path):
    old = asdict(replace(PreprocessConfig(), crop_bar=True, grayscale=True))
    out = _start(tmp_path, 0.1, old, [96, 96, 3])
    with pytest.raises(SystemExit, match="remove it to retrain"):
        ensure_start(tmp_path / "no_demos", out, 0, 0.1)


def test_vector_start_ignores_preprocessing(tmp_path):
    old = asdict(replace(PreprocessConfig(), crop_bar=True))
    out = _start(tmp_path, 0.5, old, [12])
    assert ensure_start(tmp_path / "no_demos", out, 0, 0.5) == out
