"""A fourth method added through the public API only (``register_method``): a toy improver
that scales every weight of its start, defined here. It runs as a study stage (the final
phase's stage loop, the stage runner a trial calls), as a comparison row and as a command."""

from __future__ import annotations

import copy
import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from safe_bc.methods import METHODS, Improved, MethodSpec, Start, register_method
from safe_bc.study.spec import METRICS_AFTER_STAGES as METRICS_AFTER

NAME = "nudge"


@dataclass(frozen=True)
class NudgeConfig:
    """The toy method's settings."""

    scale: float = 0.5
    """Every weight of the start is multiplied by it."""
    seed: int = 0
    """Set to the training seed by studies and comparisons (unused: the method is exact)."""

    def __post_init__(self) -> None:
        if not self.scale > 0:
            raise ValueError(f"scale must be > 0, got {self.scale}")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def run(
    config: NudgeConfig, start: Start, folder: Path, *, metadata: dict[str, Any] | None = None
) -> Improved:
    """The scaled start, written to ``folder/policy`` once (a rerun reads it back)."""
    import torch

    from safe_bc.bc.checkpoint import checkpoint_unit, load_checkpoint, save_checkpoint
    from safe_bc.rollout.evaluate import NetSource

    policy = folder / "policy"
    fresh = not (policy / "config.json").is_file()
    if fresh:
        net = copy.deepcopy(start.agent)
        with torch.no_grad():
            for p in net.parameters():
                p.mul_(config.scale)
        with checkpoint_unit(policy) as unit:
            save_checkpoint(unit, net, start.run_config.bc, extra={NAME: config.to_dict()})
    source = NetSource.from_model(*load_checkpoint(policy))
    return Improved(
        policy=source,
        net=source,
        report={"nudge_scale": config.scale},
        history=pd.DataFrame({"iteration": [1], "seconds": [0.0], "env_steps": [0]}),
        fresh=fresh,
    )


SPEC = MethodSpec(
    name=NAME,
    config=NudgeConfig,
    runner=f"{__name__}:run",
    metrics=("nudge_scale",),
    label="nudging",
)


def _assert_scaled(state: dict, start: Any, scale: float) -> None:
    """``state`` is ``start``'s with every parameter times ``scale`` (buffers as they were)."""
    params = dict(start.named_parameters())
    assert params
    for key, value in start.state_dict().items():
        factor = scale if key in params else 1.0
        np.testing.assert_allclose(state[key].numpy(), factor * value.numpy(), rtol=1e-6)


@pytest.fixture
def nudge():
    """The toy method registered for one test (the registry is left as it was)."""
    assert NAME not in METHODS
    register_method(SPEC)
    yield SPEC
    METHODS.pop(NAME)


def test_the_toy_method_is_registered_through_the_public_api(nudge) -> None:
    from dataclasses import replace

    from safe_bc.methods.stages import stage_of

    assert METHODS[NAME] is SPEC and list(METHODS)[:3] == ["improve", "queries", "selfimprove"]
    assert register_method(SPEC) is SPEC  # the same spec again: nothing changes
    with pytest.raises(ValueError, match="registered already"):
        register_method(replace(SPEC, label="other"))
    with pytest.raises(ValueError, match="takes a config of type NudgeConfig"):
        SPEC.check(object())
    assert list(METHODS)[-1] == NAME and stage_of("nudge.scale") == NAME
    assert SPEC.prefix == "nudge." and SPEC.reduce([{"nudge_scale": 0.5}]) == {"nudge_scale": 0.5}


def test_a_plugin_methods_report_reaches_the_trial_table(nudge) -> None:
    """Registered after the package was imported, its report keys are columns of the trial
    table, with the values a trial reported."""
    from safe_bc.study.spec import trial_metrics, trial_table

    assert trial_metrics()[-len(METRICS_AFTER) - 1] == "nudge_scale"
    record = {"trial_id": "a", "constraint": -1.0, "reward_mean": 1.0, "nudge_scale": 0.25}
    table = trial_table([record], params=[])
    assert table.loc[0, "nudge_scale"] == 0.25


def test_the_toy_method_runs_as_a_study_stage(nudge, rehab_demos, rehab_start, tmp_path) -> None:
    from safe_bc.methods.stages import run_stage
    from safe_bc.methods.start import start_from_checkpoint
    from safe_bc.study.final import _run_stages
    from safe_bc.study.spec import Float, StudySpec
    from safe_bc.study.trial import TrialJob
    from safe_bc.tasks import task_defaults

    env = task_defaults("rehab").env
    space = {"nudge.scale": Float(0.25, 1.0)}
    with pytest.raises(ValueError, match="searches the nudge stage"):
        StudySpec("toy", space, env=env)
    with pytest.raises(ValueError, match="no method 'other' is registered"):
        StudySpec("toy", {}, env=env, stage_configs={"other": NudgeConfig()})
    with pytest.raises(ValueError, match="takes a config of type NudgeConfig"):
        StudySpec("toy", {}, env=env, stage_configs={NAME: object()})
    spec = StudySpec(
        "toy", space, env=env, stage_configs={NAME: NudgeConfig()}, results=tmp_path / "results"
    )
    assert [stage.name for stage in spec.stages()] == [NAME]
    assert spec.stage_config(NAME, {"nudge.scale": 0.25}, seed=3) == NudgeConfig(0.25, 3)
    assert spec.summary()[NAME] == {"scale": 0.5, "seed": 0}
    assert "stage_configs" not in spec.summary()

    start = start_from_checkpoint(rehab_start)
    # the stage runner as a trial calls it
    (stage,) = spec.stages()
    name = stage.name
    source, report = run_stage(
        stage, spec.stage_config(name, {"nudge.scale": 0.25}, seed=0), start.agent,
        start.run_config, str(rehab_demos), env.env_id, tmp_path / "trial" / name,
    )  # fmt: skip
    assert report == {"nudge_scale": 0.25} and stage.reduce([report, report]) == report
    _assert_scaled(source.state, start.agent, 0.25)
    # the final phase's stage loop: every candidate's and seed's agent through the stage
    job = TrialJob(spec, str(rehab_demos), None, ())  # type: ignore[arg-type]
    candidates = pd.DataFrame({"trial_id": ["t1"], "nudge.scale": [0.5]})
    agents = _run_stages(spec, job, candidates, {("t1", 0): (start.agent, start.run_config)}, False)
    assert (tmp_path / "results/toy/final_nudge/t1/seed0/policy/config.json").is_file()
    _assert_scaled(agents[("t1", 0)].state, start.agent, 0.5)


def test_the_toy_method_is_a_comparison_row(nudge, rehab_demos, tmp_path) -> None:
    from safe_bc.bc import BCConfig, NetworkConfig, TrainConfig, load_checkpoint
    from safe_bc.compare.eval_store import FOLDER
    from safe_bc.compare.run import eval_config, run_comparison, track_seeds
    from safe_bc.compare.spec import Agent, Comparison, FromStart, Handover
    from safe_bc.data.store import read_table
    from safe_bc.distributed.evaluate import LOCKSTEP_ENVS, evaluate_policies
    from safe_bc.handover import HandoverConfig
    from safe_bc.rollout.evaluate import NetSource
    from safe_bc.selection import SelectionConfig
    from tests.conftest import rehab_collect
    from tests.test_compare import stored_evaluations

    row = FromStart("nudged", start="start", config=NudgeConfig(0.5))
    assert row.method == NAME and row.kind == NAME
    assert row.record()["method"] == NAME and row.record()["config"] == {"scale": 0.5, "seed": 0}
    comp = Comparison(
        "tiny",
        methods=(
            Agent("start", SelectionConfig(eps=0.05, alpha=0.5)),
            row,
            Handover("nudged+expert", of="nudged", handover=HandoverConfig(0.0)),
        ),
        task="rehab",
        demos=rehab_demos,
        collect=rehab_collect(),
        out=tmp_path,
        episodes=3,
        max_steps=6,
        workers=0,
        reference="start",
        bc=BCConfig(network=NetworkConfig(hidden=16), train=TrainConfig(batches=5, batch_size=8)),
    )
    table = run_comparison(comp, progress=False).set_index("method")
    assert table.loc["nudged", "mode"] == NAME and "minutes" in table
    cell = tmp_path / "tiny_runs/nudged/seed0"
    files = {policy: name for name, policy in stored_evaluations(tmp_path).items()}
    evaluated = tmp_path / FOLDER / files["nudged seed=0"]
    stamp = read_table(evaluated)[1]["stamp"]
    assert stamp["run"][NAME] == {"scale": 0.5, "seed": 0} and "start" in stamp["run"]
    assert json.loads((cell / NAME / "run.json").read_text())["python"]

    # the row's episodes are the toy's policy's, through the one evaluation path
    episodes, _ = read_table(tmp_path / "tiny_episodes.parquet")
    mine = episodes[episodes["method"] == "nudged"].set_index("env_seed")
    again, _ = evaluate_policies(
        {"x": NetSource.from_model(*load_checkpoint(cell / NAME / "policy"))}, eval_config(comp),
        thresholds=np.asarray(stamp["thresholds"]), progress=False, seeds=track_seeds(comp),
        envs_per_worker=LOCKSTEP_ENVS,
    )  # fmt: skip
    again = again.set_index("env_seed").loc[mine.index]
    np.testing.assert_array_equal(mine["reward"].to_numpy(), again["reward"].to_numpy())

    # a rerun reuses the run and every stored evaluation
    before = evaluated.stat().st_mtime_ns
    run_comparison(comp, progress=False)
    assert evaluated.stat().st_mtime_ns == before


def test_the_toy_method_is_a_command(nudge, rehab_start, tmp_path, capsys) -> None:
    from safe_bc.bc import load_checkpoint
    from safe_bc.cli.commands import main

    out = tmp_path / "nudged"
    argv = ["method", NAME, "--start", str(rehab_start), "--out", str(out),
            "--config.scale", "0.25"]  # fmt: skip
    assert main(argv) == 0
    assert "nudge_scale 0.25" in capsys.readouterr().out
    _assert_scaled(
        load_checkpoint(out / "policy")[0].state_dict(), load_checkpoint(rehab_start)[0], 0.25
    )
    assert main([*argv[:-1], "-1"]) == 2
    assert "--config.scale: scale must be > 0" in capsys.readouterr().err
    assert main(["method", "--name", "nope", "--start", "x", "--out", "y"]) == 2
    assert f"choose improve, queries, selfimprove, {NAME}" in capsys.readouterr().err
