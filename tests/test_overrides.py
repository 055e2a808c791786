"""``safe-bc tune --set FIELD=VALUE``: any StudySpec field (nested configs by dotted name)
reaches the spec the study runs with, typed and checked; a bad one is one line, exit 2,
before the study loads."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from safe_bc.cli import api
from safe_bc.cli.commands import main, parse
from safe_bc.methods.improve.config import ImproveConfig
from safe_bc.overrides import apply_overrides, parse_override
from safe_bc.study.spec import StudySpec, load_study
from safe_bc.tasks import task_defaults
from safe_bc.tasks.env_config import EnvConfig

REPO = Path(__file__).resolve().parents[1]
SMOKE = REPO / "tune_jobs" / "smoke.py"


def test_parse_override_types_values_by_their_field() -> None:
    def one(item: str):
        return parse_override(StudySpec, item)

    assert one("batches=500") == ("batches", 500)
    assert one("sampler-seed=3") == ("sampler_seed", 3)
    assert one("threshold=None") == ("threshold", None)
    assert one("threshold=0.5") == ("threshold", 0.5)
    assert one("demos=data/x") == ("demos", Path("data/x"))
    assert one("baseline=default") == ("baseline", "default")
    assert one("env.max_episode_steps=300") == ("env.max_episode_steps", 300)
    assert one("base.bc.network.channels=4,8") == ("base.bc.network.channels", (4, 8))
    assert one("base.bc.preprocess.grayscale=true") == ("base.bc.preprocess.grayscale", True)
    assert one("improve.iterations=20") == ("improve.iterations", 20)


@pytest.mark.parametrize(
    ("item", "message"),
    [
        ("batchez=5", "StudySpec has no field 'batchez' (did you mean batches"),
        ("batches", "expected FIELD=VALUE"),
        ("batches=many", "invalid literal for int()"),
        ("baseline=best", "'best' is not one of"),
        ("env.max_steps=3", "EnvConfig has no field 'max_steps'"),
        ("base=3", "a config: set its fields"),
        ("space=x", "is not set from the command line"),
        ("trials.x=1", "trials is not a config with fields"),
        ("base.bc.preprocess.grayscale=maybe", "'maybe' is not true or false"),
    ],
)
def test_bad_override_is_one_line_exit_2(
    capsys: pytest.CaptureFixture, item: str, message: str
) -> None:
    assert main(["tune", str(SMOKE), "--set", item]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"safe-bc tune: error: --set {item}: "), err
    assert message in err, err


def test_a_value_the_config_refuses_is_one_line_exit_2(
    capsys: pytest.CaptureFixture, tmp_path: Path
) -> None:
    argv = ["tune", str(SMOKE), "--results", str(tmp_path), "--set", "eval_episodes=0"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--set eval_episodes=0: " in err and ">= 1" in err, err
    assert not any(tmp_path.iterdir())  # refused before anything was written


def test_overrides_reach_the_spec_the_study_runs_with(monkeypatch: pytest.MonkeyPatch) -> None:
    seen = {}

    def fake_run_study(spec: StudySpec, **kw):
        seen["spec"] = spec
        raise KeyboardInterrupt("stopped by the test")

    monkeypatch.setattr("safe_bc.study.run.run_study", fake_run_study)
    sets = ["batches=40", "sampler_seed=7", "env=rehab", "env.max_episode_steps=30",
            "base.bc.train.lr=0.002", "improve.iterations=3", "name=smoke2"]  # fmt: skip
    _, job = parse(["tune", str(SMOKE), "--trials", "5", "--more-trials", "2", "--set", *sets])
    with pytest.raises(KeyboardInterrupt):
        api.tune(job)
    spec, file = seen["spec"], load_study(SMOKE)
    assert spec.trials == 7 and spec.batches == 40 and spec.sampler_seed == 7
    rehab = task_defaults("rehab").env
    assert spec.env == replace(rehab, max_episode_steps=30)
    assert spec.base.bc.train.lr == 0.002 and spec.base.bc.network == file.base.bc.network
    assert spec.improve == ImproveConfig(iterations=3)  # built from the defaults
    assert spec.name == "smoke2" and spec.space == file.space


def test_apply_overrides_in_order() -> None:
    spec = load_study(SMOKE)
    out = apply_overrides(spec, [("batches", 1), ("batches", 2), ("env", EnvConfig("x"))])
    assert out.batches == 2 and out.env == EnvConfig("x") and spec.batches != 2
