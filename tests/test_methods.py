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


@pytest.mark.parametrize("name", ["query", "improve"])
def test_every_old_command_is_complete(name: str) -> None:
    """A command from before ``safe-bc method NAME``: its record, its runner taking the
    distributed layer's pieces, and each ``--method``'s config field, of a registered method."""
    from safe_bc.methods import METHOD_COMMANDS, method_of_config

    command = METHOD_COMMANDS[name]
    record = command.record()
    assert record.__name__ == command.record_name and record.__dataclass_params__.frozen
    params = inspect.signature(command.load()).parameters
    assert list(params) == ["job", "parallel", "envs"]
    fields = {f.name: f for f in dataclasses.fields(record)}
    for _, field in command.configs:
        method_of_config(fields[field].default_factory())  # type: ignore[misc]


def test_a_method_command_is_checked() -> None:
    from safe_bc.methods import METHOD_COMMANDS, MethodCommand, register_command

    with pytest.raises(ValueError, match="'module:name'"):
        MethodCommand("x", "m.Job", "m:run")
    with pytest.raises(ValueError, match="at least one field"):
        MethodCommand("x", "m:Job", "m:run", configs=())
    assert register_command(METHOD_COMMANDS["query"]) is METHOD_COMMANDS["query"]
    with pytest.raises(ValueError, match="registered already"):
        register_command(MethodCommand("query", "m:Job", "m:run"))
