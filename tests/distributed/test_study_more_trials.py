"""A finished study takes more trials by asking (``safe-bc tune --more-trials N``): it resumes
its Tune experiment and Optuna sampler, runs only the new trials and reruns the final phase;
fewer trials than it ran are refused in one line."""

from __future__ import annotations

from pathlib import Path

import optuna
import pytest

from safe_bc.cli.commands import main
from safe_bc.data.store import read_table

from ..conftest import TINY_COLLECT

REPO = Path(__file__).resolve().parents[2]
SMOKE = REPO / "tune_jobs" / "smoke.py"


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_a_finished_study_takes_more_trials(tiny_demos: Path, tmp_path: Path, capsys) -> None:
    study_file = tmp_path / "tiny.py"
    study_file.write_text(
        "from dataclasses import replace\n"
        "from pathlib import Path\n"
        "from safe_bc.study.spec import load_study\n"
        "from safe_bc.rollout.collect import CollectConfig\n"
        f"STUDY = replace(load_study({str(SMOKE)!r}), demos=Path({str(tiny_demos)!r}),\n"
        f"    collect={TINY_COLLECT}, trials=2, results=Path({str(tmp_path / 'results')!r}),\n"
        "    batches=20, max_steps=60, final_episodes=1, final_workers=0, final_candidates=1,\n"
        "    final_train_seeds=1, max_concurrent=2, cpus_per_trial=0.5)\n"
    )
    argv = ["tune", str(study_file), "--storage", str(tmp_path / "ray")]
    assert main(argv) == 0, capsys.readouterr()
    out = tmp_path / "results" / "smoke"
    first, _ = read_table(out / "trials.parquet")
    assert len(first) == 2 and (out / "finished.json").exists()
    capsys.readouterr()

    assert main([*argv, "--more-trials", "1"]) == 0
    printed = capsys.readouterr().out
    assert "with 1 more trial(s), 3 in all" in printed, printed
    assert "final phase on fresh held-out tracks" in printed
    trials, _ = read_table(out / "trials.parquet")
    assert len(trials) == 3 and set(first["trial_id"]) < set(trials["trial_id"])
    # the first two were not run again: the same results
    again = trials.set_index("trial_id").loc[first["trial_id"], "reward_mean"].to_numpy()
    assert (again == first["reward_mean"].to_numpy()).all()
    study = optuna.load_study(study_name="smoke", storage=f"sqlite:///{out / 'optuna.db'}")
    assert len(study.trials) == 3
    final, _ = read_table(out / "final.parquet")
    assert len(final) >= 1 and (out / "finished.json").exists()

    # the same command again: finished with these settings, nothing runs
    assert main([*argv, "--more-trials", "1"]) == 0
    assert "finished before with these settings" in capsys.readouterr().out
    # fewer trials than it ran: one line, exit 2
    assert main([*argv, "--trials", "2"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "trials 3 -> 2" in err, err
