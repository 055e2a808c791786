"""The self-imitation choice, the report step of the self-imitation family's selection tables:
the rule; each committed choice file re-derives from its committed table through the runner's
report step; ``--report-only`` runs it alone."""

from __future__ import annotations

import re
import shutil
import sys
from pathlib import Path

import pandas as pd
import pytest

from safe_bc.compare.families import load_comparisons
from safe_bc.compare.run import run_report
from safe_bc.methods.selfimprove.choice import choose

ROOT = Path(__file__).resolve().parents[1]
FAMILY = ROOT / "tune_jobs/compare/selfimprove.py"
REPORTED = {
    key: c for key, c in load_comparisons(FAMILY, planned=True).items() if c.report is not None
}
"""The family's comparisons with a report step, by address."""


def test_the_rule_wants_a_reliable_gain_then_fewest_crossings_then_reward() -> None:
    t = pd.DataFrame(
        {"d_reward_lo": [0.1, 0.2, 0.3, -0.1], "b": [5, 3, 3, 0], "reward": [1.0, 2.0, 2.5, 9.0]},
        index=["defaults", "x", "y", "z"],
    )
    assert choose(t, "b", list(t.index))[0] == "y"  # z has no reliable gain; x ties on b
    assert choose(t, "b", ["defaults", "z"])[0] == "defaults"
    assert choose(t, "b", ["z"])[0] is None


def test_the_selection_tables_declare_the_choice() -> None:
    files = {key: f"{c.out.name}/{c.report.file}" for key, c in REPORTED.items()}  # type: ignore[union-attr]
    assert files == {
        "selection_carracing": "carracing/choice.md",
        "rounds_carracing": "carracing/rounds_choice.md",
        "selection_rehab": "rehab/choice.md",
    }


def _committed_elsewhere(tmp_path: Path, key: str, monkeypatch) -> tuple[Path, str]:
    """The comparison ``key``'s committed table copied to the same relative path under
    ``tmp_path`` (the working folder now); its committed choice file's text."""
    c = REPORTED[key]
    table = c.out / f"{c.name}.parquet"
    (tmp_path / c.out).mkdir(parents=True)
    shutil.copyfile(ROOT / table, tmp_path / table)
    monkeypatch.chdir(tmp_path)
    return c.out / c.report.file, (ROOT / c.out / c.report.file).read_text()  # type: ignore[union-attr]


@pytest.mark.parametrize("key", sorted(REPORTED))
def test_committed_choice_rederives_through_the_report_step(
    key: str, tmp_path: Path, monkeypatch
) -> None:
    """Byte for byte, given the command the committed file records (the script the step was
    before)."""
    out, committed = _committed_elsewhere(tmp_path, key, monkeypatch)
    (command,) = re.findall(r"Command: `([^`]*)`", committed)
    assert run_report(REPORTED[key], command) == [out]
    assert out.read_text() == committed


def test_report_only_runs_the_step_alone(tmp_path: Path, monkeypatch) -> None:
    """``safe-bc compare ... --report-only`` writes the choice from the table on disk, recording
    itself as the command; a comparison without a report step, or without its table, is one
    line (exit 2)."""
    from safe_bc.cli.commands import main

    out, committed = _committed_elsewhere(tmp_path, "selection_rehab", monkeypatch)
    argv = ["compare", "tune_jobs/compare/selfimprove.py", "--name", "selection_rehab"]
    (tmp_path / "tune_jobs/compare").mkdir(parents=True)
    shutil.copyfile(FAMILY, tmp_path / argv[1])
    monkeypatch.setattr(sys, "argv", ["safe-bc", *argv, "--report-only"])
    assert main([*argv, "--report-only"]) == 0
    text = out.read_text()
    assert text.endswith(f"Command: `{' '.join(sys.argv)}`.\n")
    assert text.splitlines()[:-1] == committed.splitlines()[:-1]
    assert main(["compare", str(FAMILY), "--name", "compare_rehab", "--report-only"]) == 2
    assert main(["compare", str(FAMILY), "--name", "selection_carracing", "--report-only"]) == 2
    assert main([*argv, "--report-only", "--render-only"]) == 2
