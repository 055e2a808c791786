"""The command line: one-line errors with exit code 2 (an unreachable RAY_ADDRESS before
anything is written, a study file that fails to import), every selection setting on
``safe-bc train``, and a study in which no trial finished."""

from __future__ import annotations

import dataclasses
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from safe_bc.cli import SELECTION_FLAGS, _selection_config, build_parser, main
from safe_bc.data.store import init_dataset, read_table, write_episode
from safe_bc.selection import SelectionConfig
from safe_bc.study import load_study, trial_table

from .data.test_store import make_episode, make_meta
from .distributed.test_runtime import refused_address

REPO = Path(__file__).resolve().parents[1]
SMOKE = REPO / "tune_jobs" / "smoke.py"


def test_unreachable_ray_address_fails_fast_and_writes_nothing(tmp_path: Path) -> None:
    sock, address = refused_address()
    out = tmp_path / "demos"
    with sock:
        start = time.perf_counter()
        proc = subprocess.run(
            [sys.executable, "-m", "safe_bc.cli", "collect", "--episodes", "1", "--out", str(out)],
            env={**os.environ, "RAY_ADDRESS": address},
            capture_output=True,
            text=True,
            timeout=120,
        )
        seconds = time.perf_counter() - start
    assert proc.returncode == 2, proc.stderr
    err = proc.stderr.strip()
    assert "\n" not in err and err.startswith("safe-bc collect: error: ") and address in err
    assert not out.exists()
    assert seconds < 30


def test_unreachable_ray_address_stops_tune_before_it_starts(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    sock, address = refused_address()
    monkeypatch.setenv("RAY_ADDRESS", address)
    with sock:
        code = main(["tune", str(SMOKE), "--results", str(tmp_path), "--storage", str(tmp_path)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and f"RAY_ADDRESS={address}" in err
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize(
    ("text", "line", "problem"),
    [
        ('"""doc"""\nSTUDY = StudySpec(\n    name="x"\n    trials=2,\n)\n', 3, "SyntaxError"),
        (
            '"""doc"""\n\nfrom safe_bc.no_such_module import thing\n',
            3,
            "ModuleNotFoundError: No module named 'safe_bc.no_such_module'",
        ),
        (
            "from safe_bc.study import Float, StudySpec\n\n"
            'STUDY = StudySpec("x", {"selection.eps": Float(2.0, 1.0)})\n',
            3,
            "ValueError: Float needs finite low <= high",
        ),
    ],
)
def test_broken_study_file_is_one_line_naming_file_and_line(
    tmp_path: Path, capsys: pytest.CaptureFixture, text: str, line: int, problem: str
) -> None:
    study = tmp_path / "broken.py"
    study.write_text(text)
    with pytest.raises(ValueError, match=re.escape(problem)):
        load_study(study)
    assert "safe_bc_tune_jobs_broken" not in sys.modules
    code = main(["tune", str(study)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err, err
    assert err.startswith(f"safe-bc tune: error: {study}:{line}: ") and problem in err


def test_every_selection_setting_is_a_train_flag() -> None:
    assert set(SELECTION_FLAGS) == {f.name for f in dataclasses.fields(SelectionConfig)}
    args = build_parser().parse_args(
        ["train", "--out", "x", "--threshold", "quantile", "--quantile", "0.9", "--combine", "all"]
    )
    assert _selection_config(args, eps=3.0) == SelectionConfig(
        eps=3.0, threshold="quantile", quantile=0.9, combine="all"
    )
    args = build_parser().parse_args(["train", "--out", "x", "--mode", "cost_weighted"])
    assert _selection_config(args, eps=2.0) == SelectionConfig(eps=2.0, mode="cost_weighted")
    args = build_parser().parse_args(["train", "--out", "x", "--quantile", "0.9"])
    with pytest.raises(ValueError, match="--quantile applies with --threshold quantile"):
        _selection_config(args)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--quantile", "1.5"], "--quantile must be in (0, 1], got 1.5"),
        (["--quantile", "0"], "--quantile must be in (0, 1], got 0.0"),
        (["--quantile", "high"], "--quantile must be a number, got 'high'"),
        (["--combine", "most"], "argument --combine: invalid choice: 'most'"),
        (["--threshold", "mean"], "argument --threshold: invalid choice: 'mean'"),
        (["--segment-steps", "0"], "--segment-steps must be >= 1, got 0"),
        (["--beta", "inf"], "--beta must be finite, >= 0, got inf"),
    ],
)
def test_bad_selection_flags_exit_2(
    capsys: pytest.CaptureFixture, argv: list[str], message: str
) -> None:
    with pytest.raises(SystemExit) as info:
        main(["train", "--out", "x", *argv])
    assert info.value.code == 2
    assert message in capsys.readouterr().err.strip().splitlines()[-1]


def test_train_records_quantile_and_combine(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    demos = tmp_path / "demos"
    meta = init_dataset(demos, make_meta("raw"))
    for i in range(2):
        write_episode(demos, make_episode(i, n=20), meta)
    out = tmp_path / "run"
    flags = ["--threshold", "quantile", "--quantile", "0.9", "--combine", "all"]
    small = ["--batches", "2", "--batch-size", "4", "--hidden", "8", "--alpha", "0", "--quiet"]
    assert main(["train", "--demos", str(demos), "--out", str(out), *flags, *small]) == 0
    _, sel = read_table(out / "selection.parquet")
    assert sel["config"]["quantile"] == 0.9 and sel["config"]["combine"] == "all"
    assert sel["config"]["threshold"] == "quantile"
    code = main(["train", "--demos", str(demos), "--out", str(out), "--quantile", "0.9"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.endswith("--quantile applies with --threshold quantile")


def _invalid_outcome(tmp_path: Path):
    from safe_bc.distributed.study import StudyOutcome

    errors = [
        "alpha=0.63 < 1 but the rest pool is empty (critical=74)",
        "training diverged (loss nan)",
        "alpha=0.5 < 1 but the rest pool is empty (critical=74)",
    ]
    records = [
        {"trial_id": f"t{i}", "status": "invalid", "error": e, "reward_mean": np.nan}
        for i, e in enumerate(errors)
    ]
    trials = trial_table(records, ["selection.eps"])
    return StudyOutcome(True, trials, None, None, 6.0, tmp_path / "s", str(tmp_path), 0)


def test_study_without_a_finished_trial_says_why_and_fails(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    import safe_bc.distributed.study as study

    outcome = _invalid_outcome(tmp_path)
    text = study.format_outcome(outcome, ["selection.eps"])
    lines = text.splitlines()
    why = lines.index("no trial finished its evaluation; why:")
    assert lines[why + 1 : why + 3] == [
        "  2 trial(s): alpha=0.63 < 1 but the rest pool is empty (critical=74) (numbers differ "
        "between the trials)",
        "  1 trial(s): training diverged (loss nan)",
    ]

    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    monkeypatch.setattr(study, "run_study", lambda spec, **kw: outcome)
    assert main(["tune", str(SMOKE)]) == 1
    assert "rest pool is empty" in capsys.readouterr().out


def test_study_summary_without_errors_says_so(tmp_path: Path) -> None:
    from safe_bc.distributed.study import format_outcome

    outcome = _invalid_outcome(tmp_path)
    trials = outcome.trials.assign(error="")
    text = format_outcome(dataclasses.replace(outcome, trials=trials), ["selection.eps"])
    assert "no trial finished its evaluation (no trial recorded an error)" in text


def test_preprocessing_and_channels_are_train_flags_with_the_config_defaults() -> None:
    from safe_bc.bc.config import NetworkConfig, PreprocessConfig

    args = build_parser().parse_args(["train", "--out", "x"])
    pre = PreprocessConfig()
    assert (args.crop_bar, args.grayscale, args.mask_steering, args.frame_stack) == (
        pre.crop_bar, pre.grayscale, pre.mask_steering, pre.frame_stack
    )  # fmt: skip
    assert args.channels is None and NetworkConfig().channels
    args = build_parser().parse_args(
        ["train", "--out", "x", "--no-crop-bar", "--no-grayscale", "--mask-steering",
         "--frame-stack", "4", "--channels", "8", "16", "16"]
    )  # fmt: skip
    assert (args.crop_bar, args.grayscale, args.mask_steering, args.frame_stack) == (
        False, False, True, 4
    )  # fmt: skip
    assert args.channels == [8, 16, 16]


def test_every_key_the_default_study_searches_is_a_train_flag() -> None:
    """A study's winner can be retrained with one ``safe-bc train`` command."""
    study = load_study(REPO / "tune_jobs" / "default.py")
    options = {
        opt for action in build_parser()._subparsers._group_actions[0].choices["train"]._actions
        for opt in action.option_strings
    }  # fmt: skip
    for key in study.space:
        flag = "--" + key.rsplit(".", 1)[-1].replace("_", "-")
        assert flag in options, f"{key} has no train flag {flag}"


def test_every_option_of_every_verb_has_help():
    import argparse

    from safe_bc.cli import build_parser

    (verbs,) = [a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)]
    missing = [
        f"{verb} {'/'.join(action.option_strings) or action.dest}"
        for verb, sub in verbs.choices.items()
        for action in sub._actions
        if not isinstance(action, argparse._HelpAction) and not action.help
    ]
    assert not missing, missing
