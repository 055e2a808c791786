"""The command line generated from the configs: one-line errors with exit code 2 (bad flags
and values, an unreachable RAY_ADDRESS before anything is written, a study file that fails
to import), every config field a dotted flag with the config's default and help, and a
study in which no trial finished."""

from __future__ import annotations

import contextlib
import dataclasses
import io
import itertools
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from safe_bc.cli.commands import COMMANDS, main, parse
from safe_bc.data.store import init_dataset, read_table, write_episode
from safe_bc.selection import SelectionConfig
from safe_bc.study.spec import load_study, trial_table

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
            [
                sys.executable,
                "-m",
                "safe_bc.cli.commands",
                "collect",
                "--episodes",
                "1",
                "--out",
                str(out),
            ],
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
            "from safe_bc.study.spec import Float, StudySpec\n\n"
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


def test_every_selection_setting_is_a_dotted_train_flag() -> None:
    argv = ["train", "--out", "x", "--selection.threshold", "quantile", "--selection.quantile",
            "0.9", "--selection.combine", "all", "--selection.eps", "3"]  # fmt: skip
    assert parse(argv)[1].run.selection == SelectionConfig(
        eps=3.0, threshold="quantile", quantile=0.9, combine="all"
    )
    _, job = parse(["train", "--out", "x", "--selection.mode", "cost_weighted"])
    assert job.run.selection == SelectionConfig(mode="cost_weighted")
    names = {f.name for f in dataclasses.fields(SelectionConfig)}
    assert names <= {f.split(".", 1)[1] for f in _flags("train") if f.startswith("selection.")}


def _flags(command: str) -> set[str]:
    """The dotted flags ``safe-bc COMMAND --help`` lists (hyphens as underscores)."""
    return {f.replace("-", "_") for f in re.findall(r"--([\w.-]+)", _help(command))}


def _help(command: str) -> str:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit) as info:
        parse([command, "--help"])
    assert info.value.code == 0
    return out.getvalue()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--selection.quantile", "1.5"], "--selection.quantile: quantile must be in (0, 1]"),
        (["--selection.quantile", "high"], "--selection.quantile: could not convert string"),
        (["--selection.combine", "most"], "invalid choice 'most' for argument '--selection.comb"),
        (["--selection.threshold", "mean"], "invalid choice 'mean'"),
        (
            ["--selection.mode", "bc_safe", "--selection.segment-steps", "0"],
            "--selection.segment-steps: segment_steps must be",
        ),
        (["--selection.alpha", "1.5"], "--selection.alpha: alpha must be in [0, 1], got alpha=1.5"),
        (["--bc.train.lr", "inf"], "--bc.train.lr: lr must be a finite number > 0"),
        (["--bc.network.channels", "8", "0", "4"], "--bc.network.channels: channels[i] must"),
        (["--bc.train.batch_size", "x"], "--bc.train.batch-size"),
        (["--no-such-flag", "1"], "unrecognized option(s) --no-such-flag"),
        (["--lr", "0.1"], "unrecognized option(s) --lr; did you mean --bc.train.lr?"),
        (["--selection.quantile", "0.9"], "--selection.quantile applies with --selection.thre"),
        (["--selection.beta", "2"], "--selection.beta applies with --selection.mode cost_weighted"),
    ],
)
def test_bad_train_flags_are_one_line_exit_2(
    capsys: pytest.CaptureFixture, argv: list[str], message: str
) -> None:
    assert main(["train", "--out", "x", *argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("safe-bc train: error: "), err
    assert message in err, err
    assert "``" not in err and "(default:" not in err  # names, not the suggested flags' docs


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        ([], "safe-bc: error: choose a command: collect, describe, train"),
        (["fly"], "safe-bc: error: unknown command 'fly'"),
        (["train"], "safe-bc train: error: Missing from safe-bc train: --out PATH"),
        (["collect", "--episodes", "0", "--env", "rehab"], "episodes must be >= 1, got 0"),
        (["improve", "--start", "a", "--out", "b", "--iterations", "0"], "--iterations: "),
        (["render", "--out", "x.gif", "--scale", "0"], "--scale: scale must be >= 1, got 0"),
        (["reproduce", "--alphas", "0", "2"], "alpha must be in [0, 1], got 2.0"),
        (
            ["tune", "tune_jobs/smoke.py", "--trials", "many"],
            "--trials: no type matching {None}|INT could be instantiated from ['many']",
        ),
        (["evaluate", "--out", "x"], "evaluate needs --checkpoint DIR (an agent) or --recommender"),
    ],
)
def test_bad_input_of_other_commands_is_one_line_exit_2(
    capsys: pytest.CaptureFixture, argv: list[str], message: str
) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err  # an old command's name too: its new form only once parsed
    assert err.count("\n") == 1 and message in err, err


@pytest.mark.parametrize("command", list(COMMANDS))
def test_help_of_every_command_lists_its_fields_each_with_help(command: str) -> None:
    from safe_bc.cli import jobs

    text = _help(command)
    cls = getattr(jobs, COMMANDS[command][0])
    for f in dataclasses.fields(cls):
        if f.name in ("run", "config", "study", "comparison"):  # flattened configs, positionals
            continue
        assert f"--{f.name.replace('_', '-')}" in text, (command, f.name)
    rows = [line.strip("│ ") for line in text.splitlines()] + [""]
    for row, below in itertools.pairwise(rows):
        if row.startswith("--") and not row.startswith("--help"):  # the help beside or below
            doc = (re.split(r" {2,}", row, maxsplit=1)[1:] or [below])[0]
            assert doc and not doc.startswith("(default"), f"{command} {row} has no help"


@pytest.mark.parametrize(
    ("argv", "new"),
    [
        (["query"], "`safe-bc query` is `safe-bc method queries` now"),
        (["improve"], "`safe-bc improve` is `safe-bc method improve` now"),
        (
            ["improve", "--method", "selfimitation"],
            "`safe-bc improve` is `safe-bc method selfimprove` now",
        ),
        (
            ["improve", "--method=selfimitation"],
            "`safe-bc improve` is `safe-bc method selfimprove` now",
        ),
    ],
)
def test_the_old_method_commands_name_the_new_form_and_still_run(
    capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch, argv: list[str], new: str
) -> None:
    """``query`` and ``improve`` work as before (their help; their own flags parse to their
    records) and print one line to stderr giving ``safe-bc method NAME``: with their help, and
    once they ran (a parse error keeps its one line)."""
    import safe_bc.cli.commands as commands

    with pytest.raises(SystemExit) as info:
        parse([*argv, "--help"])
    assert info.value.code == 0
    captured = capsys.readouterr()
    assert captured.err == new + "\n" and f"safe-bc {argv[0]}" in captured.out
    full = [argv[0], "--checkpoint" if argv[0] == "query" else "--start", "a", "--out", "b",
            *argv[1:], *(["--demos", "d"] if argv[0] == "query" else [])]  # fmt: skip
    job = parse(full)[1]
    assert type(job).__name__ == COMMANDS[argv[0]][0]
    assert capsys.readouterr().err == ""
    monkeypatch.setattr(commands, "run", lambda *_: 0)
    assert main(full) == 0
    assert capsys.readouterr().err == new + "\n"


def test_method_takes_its_name_first(capsys: pytest.CaptureFixture) -> None:
    """``safe-bc method NAME ...`` (``--name NAME`` too), no line about an old name."""
    first = parse(["method", "queries", "--start", "a", "--out", "b", "--config.rounds", "3"])[1]
    named = parse(["method", "--name", "queries", "--start", "a", "--out", "b",
                   "--config.rounds", "3"])[1]  # fmt: skip
    assert first == named and first.name == "queries" and first.config.rounds == 3
    assert capsys.readouterr().err == ""


def test_top_level_help_lists_every_command(capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(SystemExit) as info:
        main(["--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    assert all(f"  {c} " in out for c in COMMANDS)


def test_default_records_are_the_configs_defaults() -> None:
    """The same command line builds the same configs: nothing given, the dataclass defaults."""
    from safe_bc.cli.jobs import CollectJob, DescribeJob, ExpertJob, TrainJob
    from safe_bc.compare.reproduce import ReproduceConfig
    from safe_bc.methods.improve import ImproveConfig
    from safe_bc.rollout.evaluate import EvalConfig
    from safe_bc.run_config import RunConfig

    assert parse(["train", "--out", "x"])[1] == TrainJob(Path("x"))
    assert parse(["train", "--out", "x"])[1].run == RunConfig()
    assert parse(["improve", "--start", "a", "--out", "b"])[1].config == ImproveConfig()
    assert parse(["reproduce"])[1].config == ReproduceConfig()
    job = parse(["evaluate", "--checkpoint", "c", "--out", "o"])[1]
    assert (job.episodes, job.workers, job.eval_seed, job.max_steps) == (
        EvalConfig.episodes, EvalConfig.workers, EvalConfig.seed, EvalConfig.max_steps
    )  # fmt: skip
    assert parse(["collect"])[1] == CollectJob()
    assert parse(["describe"])[1] == DescribeJob()
    assert parse(["expert"])[1] == ExpertJob()
    tune = parse(["tune", "tune_jobs/default.py"])[1]
    assert tune.study == Path("tune_jobs/default.py") and tune.overrides() == {}


def test_short_flags_and_task_defaults() -> None:
    _, job = parse(["train", "--out", "x", "--seed", "3", "--bc.train.lr=1e-3"])
    assert job.run.bc.train.seed == 3 and job.run.bc.train.lr == 1e-3
    _, job = parse(["reproduce", "--env", "rehab"])
    assert (job.config.task, job.config.demos, job.config.out) == (
        "rehab", Path("data/rehab_demos"), Path("results/rehab")
    )  # fmt: skip
    _, job = parse(["reproduce", "--task", "rehab", "--out", "o"])
    assert job.config.demos == Path("data/rehab_demos") and job.config.out == Path("o")
    _, job = parse(["tune", "s.py", "--trials", "3", "--max-concurrent", "1", "--fresh"])
    assert job.overrides() == {"trials": 3, "max_concurrent": 1} and job.fresh
    assert not job.verbose and parse(["tune", "s.py", "--verbose"])[1].verbose  # Tune's table


def test_handover_flags_carry_the_configs_names_and_keep_the_old_ones() -> None:
    import dataclasses

    from safe_bc.handover import HandoverConfig

    base = ["evaluate", "--checkpoint", "c", "--out", "o"]
    new = parse([*base, "--handover.width", "2", "--handover.hold", "6",
                 "--handover.lookahead", "6", "--handover.hold-on", "front"])[1]  # fmt: skip
    old = parse([*base, "--defer-width", "2", "--defer-hold=6", "--defer-lookahead", "6",
                 "--defer-hold-on", "front"])[1]  # fmt: skip
    assert new == old
    h = new.handover
    assert HandoverConfig(h.width, h.lookahead, h.hold, h.hold_on) == HandoverConfig(
        2.0, lookahead=6, hold=6, hold_on=("front",)
    )
    # every flag but the width (None: no handover) is a field of HandoverConfig of that name
    names = {f.name for f in dataclasses.fields(HandoverConfig)}
    assert {f.name for f in dataclasses.fields(h)} <= names
    assert not parse(base)[1].handover.given and h.given


def test_train_records_quantile_and_combine(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    demos = tmp_path / "demos"
    meta = init_dataset(demos, make_meta("raw"))
    for i in range(2):
        write_episode(demos, make_episode(i, n=20), meta)
    out = tmp_path / "run"
    flags = ["--selection.threshold", "quantile", "--selection.quantile", "0.9",
             "--selection.combine", "all"]  # fmt: skip
    small = ["--bc.train.batches", "2", "--bc.train.batch-size", "4", "--bc.network.hidden", "8",
             "--selection.alpha", "0", "--quiet"]  # fmt: skip
    assert main(["train", "--demos", str(demos), "--out", str(out), *flags, *small]) == 0
    _, sel = read_table(out / "selection.parquet")
    assert sel["config"]["quantile"] == 0.9 and sel["config"]["combine"] == "all"
    assert sel["config"]["threshold"] == "quantile"
    assert "trained 2 batches" in capsys.readouterr().out


def _invalid_outcome(tmp_path: Path):
    from safe_bc.study.run import StudyOutcome

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
    import safe_bc.study.run as study

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
    from safe_bc.study.run import format_outcome

    outcome = _invalid_outcome(tmp_path)
    trials = outcome.trials.assign(error="")
    text = format_outcome(dataclasses.replace(outcome, trials=trials), ["selection.eps"])
    assert "no trial finished its evaluation (no trial recorded an error)" in text


def test_the_study_summary_names_episodes_in_the_tasks_words(tmp_path: Path) -> None:
    """The closing summary calls the final phase's episodes what the task calls them
    (``StudyOutcome.unit``, the task's ``episodes_name``): no "tracks" for another task."""
    import pandas as pd

    from safe_bc.study.final import FinalOutcome
    from safe_bc.study.run import format_outcome

    table = pd.DataFrame(
        {
            "method": ["t0", "expert"],
            "n_train_seeds": [1, 1],
            "n_episodes": [4, 4],
            "reward": [1.0, 2.0],
            "feasible": [True, True],
        }
    )
    paired = pd.DataFrame({"method": ["t0"], "vs": ["expert"], "d_reward": [-1.0],
                           "d_reward_lo": [-2.0], "d_reward_hi": [0.0]})  # fmt: skip
    final = FinalOutcome(table, pd.DataFrame(), "t0", True, "chosen", {}, "0 of 4", paired)
    outcome = dataclasses.replace(_invalid_outcome(tmp_path), final=final)
    for unit in ("patients", "episodes", "tracks"):
        text = format_outcome(dataclasses.replace(outcome, unit=unit), ["selection.eps"])
        assert f"final phase on fresh held-out {unit} (" in text
        assert f"on the fresh {unit}: 0 of 4" in text and f"(paired, same {unit})" in text
        assert ("track" in text) == (unit == "tracks")


def test_preprocessing_and_network_are_dotted_train_flags() -> None:
    from safe_bc.bc.config import PreprocessConfig

    _, job = parse(
        ["train", "--out", "x", "--bc.preprocess.crop-bar", "--bc.preprocess.no-mask-steering",
         "--bc.preprocess.frame-stack", "4", "--bc.network.channels", "8", "16", "16"]
    )  # fmt: skip
    assert job.run.bc.preprocess == PreprocessConfig(
        crop_bar=True, mask_steering=False, frame_stack=4
    )
    assert job.run.bc.network.channels == (8, 16, 16)


def test_every_key_the_default_study_searches_is_a_train_flag() -> None:
    """A study's winner can be retrained with one ``safe-bc train`` command: each searched
    key, by its dotted name, sets that field."""
    study = load_study(REPO / "tune_jobs" / "default.py")
    for key, param in study.space.items():
        value = param.options[0] if hasattr(param, "options") else param.low
        words = [str(v) for v in value] if isinstance(value, tuple) else [str(value)]
        _, job = parse(["train", "--out", "x", f"--{key}", *words])
        got = job.run
        for part in key.split("."):
            got = getattr(got, part)
        assert got == value, key


def test_collect_train_evaluate_through_the_cli(ray_session, tmp_path: Path, capsys) -> None:
    """A real short run: rehab demonstrations, an agent with the task's eps, its evaluation."""
    import pandas as pd

    from safe_bc.tasks import task_defaults

    demos, ckpt, out = tmp_path / "demos", tmp_path / "ckpt", tmp_path / "eval"
    argv = ["collect", "--env", "rehab", "--episodes", "2", "--workers", "1", "--out", str(demos),
            "--quiet"]  # fmt: skip
    assert main(argv) == 0
    assert "2 episode(s) collected" in capsys.readouterr().out
    argv = ["train", "--demos", str(demos), "--out", str(ckpt), "--bc.train.batches", "3",
            "--bc.network.hidden", "8", "--seed", "1", "--quiet"]  # fmt: skip
    assert main(argv) == 0
    _, sel = read_table(ckpt / "selection.parquet")
    assert sel["config"]["eps"] == task_defaults("rehab").eps != SelectionConfig().eps
    argv = ["evaluate", "--checkpoint", str(ckpt), "--episodes", "2", "--workers", "0",
            "--out", str(out), "--quiet"]  # fmt: skip
    assert main(argv) == 0
    assert len(pd.read_parquet(out / "episodes.parquet")) == 2
    printed = capsys.readouterr().out
    assert "safety_mean" in printed and "too few episodes for an interval" in printed
    assert "95% CI" not in printed  # two episodes: the means alone


def test_expert_from_few_episodes_reports_means_without_an_interval(
    rehab_demos: Path, tmp_path: Path, capsys
) -> None:
    out = tmp_path / "expert"
    argv = ["expert", "--env", "rehab", "--demos", str(rehab_demos), "--episodes", "2",
            "--workers", "0", "--out", str(out), "--quiet"]  # fmt: skip
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "too few episodes for an interval" in printed and "95% CI" not in printed
    assert (out / "expert.md").read_text().strip() == printed.strip()
    from safe_bc.data.store import data_digest  # the table names the demonstrations it read

    assert read_table(out / "expert.parquet")[1]["inputs"]["demos"]["digest"] == data_digest(
        rehab_demos
    )


def test_describe_names_the_set_by_its_content_digest(tiny_demos, tmp_path) -> None:
    import json

    from safe_bc.cli.commands import main
    from safe_bc.data.store import data_digest

    assert main(["describe", "--demos", str(tiny_demos), "--out", str(tmp_path / "d")]) == 0
    summary = json.loads((tmp_path / "d" / "summary.json").read_text())
    assert summary["digest"] == data_digest(tiny_demos) and summary["digest"].startswith("sha256:")


def test_python_m_safe_bc_cli_exits_with_the_commands_status(tmp_path) -> None:
    """``python -m safe_bc.cli`` is the ``safe-bc`` command, its exit status too (a refused
    input must not read as success to a script or ``make``)."""
    import subprocess
    import sys

    bad = subprocess.run([sys.executable, "-m", "safe_bc.cli", "tune", str(tmp_path / "none.py")],
                         capture_output=True, text=True, cwd=tmp_path)  # fmt: skip
    assert bad.returncode == 2 and "none.py" in bad.stderr
    ok = subprocess.run([sys.executable, "-m", "safe_bc.cli", "--help"], capture_output=True)
    assert ok.returncode == 0
