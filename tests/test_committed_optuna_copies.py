"""Every committed study's Optuna copy says what the study decided: its objective's name, the
screened trials PRUNED, the final phase's winner marked, as a study writes its copy."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from safe_bc.data.store import read_table
from safe_bc.study.search import WINNER

ROOT = Path(__file__).resolve().parents[1]
COPIES = sorted(
    p.parent
    for p in (ROOT / "results").rglob("optuna.db")
    if (p.parent / "trials.parquet").is_file()
)


@pytest.mark.parametrize("folder", COPIES, ids=lambda p: str(p.relative_to(ROOT)))
def test_a_committed_optuna_copy_carries_the_studys_decisions(folder: Path) -> None:
    import optuna

    optuna.logging.set_verbosity(optuna.logging.ERROR)
    url = f"sqlite:///{folder / 'optuna.db'}"
    (name,) = optuna.study.get_all_study_names(url)
    study = optuna.load_study(study_name=name, storage=url)
    trials, meta = read_table(folder / "trials.parquet")
    assert study.metric_names == [meta.get("objective", "reward_mean")]
    pruned = {t.user_attrs.get("tune_trial_id") for t in study.trials if t.state.name == "PRUNED"}
    assert pruned == set(trials.loc[trials["status"] == "stopped", "trial_id"])
    best = (
        json.loads((folder / "best.json").read_text()) if (folder / "best.json").is_file() else {}
    )
    winner = best.get("trial_id")  # marked feasible or not, as the study marks it
    assert study.user_attrs.get(WINNER) == winner
    assert study.user_attrs.get("final_winner_feasible") == bool(best.get("feasible"))
    marked = [t.user_attrs.get("tune_trial_id") for t in study.trials if t.user_attrs.get(WINNER)]
    assert marked == ([winner] if winner else [])
    assert all("constraints" in t.system_attrs for t in study.trials if t.constraints)


def test_every_committed_study_with_a_copy_is_checked() -> None:
    assert len(COPIES) >= 3
