"""The method registry: every entry is complete (config record, runner, identity, metrics)."""

from __future__ import annotations

import dataclasses
import inspect
import json

import pytest

from safe_bc.methods import METHODS


@pytest.mark.parametrize("name", list(METHODS))
def test_every_method_is_complete(name: str) -> None:
    spec = METHODS[name]
    config = spec.config()  # every setting has a default
    assert dataclasses.fields(config) and config.__dataclass_params__.frozen
    assert config.to_dict()["seed"] == 0
    params = inspect.signature(spec.load()).parameters
    assert list(params)[:3] == ["config", "start", "folder"] and "metadata" in params
    for task in ("carracing", "rehab"):
        json.dumps(spec.identify(config, task))
    assert spec.metrics and all(m.startswith(f"{name}_") for m in spec.metrics)


def test_metrics_of_methods_are_distinct() -> None:
    metrics = [m for spec in METHODS.values() for m in spec.metrics]
    assert len(metrics) == len(set(metrics))


def test_a_method_spec_is_checked() -> None:
    from safe_bc.methods import MethodSpec, method_of
    from safe_bc.methods.improve.config import ImproveConfig

    with pytest.raises(ValueError, match="identifier"):
        MethodSpec("two words", ImproveConfig, "m:f")
    with pytest.raises(ValueError, match="a dataclass type"):
        MethodSpec("x", dict, "m:f")
    with pytest.raises(ValueError, match="'module:function'"):
        MethodSpec("x", ImproveConfig, "m.f")
    with pytest.raises(ValueError, match="summed"):
        MethodSpec("x", ImproveConfig, "m:f", metrics=("a",), summed=("b",))
    with pytest.raises(ValueError, match="unknown method 'x': choose improve, queries"):
        method_of("x")
